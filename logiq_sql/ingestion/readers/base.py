"""What every format reader hands to the writer: one DriveData per drive."""

from __future__ import annotations

from dataclasses import dataclass, field

import polars as pl

from logiq_sql.core import schema

# one empty frame per table, shared by every drive without rows of it: Polars frames are not changed in place (a
# reader that fills one replaces it), and building a new one for each drive cost more than some readers' rows
_EMPTY = {t.name: schema.empty(t) for t in (*schema.MAP_TABLES, schema.TRAFFIC_LIGHT_STATES)}


@dataclass
class DriveData:
    """A drive read from a source, in canonical columns.

    Attributes:
        drive_id: unique id (e.g. the file stem or the scene name).
        source_format: reader name (``commonroad``, ``scenarionet``, ``parquet``, ``sumo``, ``av2``).
        source_path: the file it came from.
        dt_s: sample period, seconds.
        tracks: rows of ``schema.TRACKS`` (heading/speed/accel/size may be null: derived later).
        map_id: key of this drive's map in the map tables, or None.
        lanes, lane_successors, junctions, traffic_lights: rows of the map tables for ``map_id``.
        traffic_light_states: rows of ``schema.TRAFFIC_LIGHT_STATES`` for this drive.
        ego_actor_id: the recorded ego, or None.
        rows_rejected / reject_reason: rows the reader dropped and why.
        attribution: licence text to carry into ``drive_inputs``.
    """

    drive_id: str
    source_format: str
    source_path: str
    dt_s: float
    tracks: pl.DataFrame
    map_id: str | None = None
    lanes: pl.DataFrame = field(default_factory=lambda: _EMPTY["lanes"])
    lane_successors: pl.DataFrame = field(default_factory=lambda: _EMPTY["lane_successors"])
    junctions: pl.DataFrame = field(default_factory=lambda: _EMPTY["junctions"])
    traffic_lights: pl.DataFrame = field(default_factory=lambda: _EMPTY["traffic_lights"])
    traffic_light_states: pl.DataFrame = field(default_factory=lambda: _EMPTY["traffic_light_states"])
    ego_actor_id: str | None = None
    rows_read: int = 0
    rows_rejected: int = 0
    reject_reason: str | None = None
    attribution: str | None = None
