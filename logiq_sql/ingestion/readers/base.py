"""What every format reader hands to the writer: one DriveData per drive."""

from __future__ import annotations

from dataclasses import dataclass, field

import polars as pl

from logiq_sql.core import schema


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
    lanes: pl.DataFrame = field(default_factory=lambda: schema.empty(schema.LANES))
    lane_successors: pl.DataFrame = field(default_factory=lambda: schema.empty(schema.LANE_SUCCESSORS))
    junctions: pl.DataFrame = field(default_factory=lambda: schema.empty(schema.JUNCTIONS))
    traffic_lights: pl.DataFrame = field(default_factory=lambda: schema.empty(schema.TRAFFIC_LIGHTS))
    traffic_light_states: pl.DataFrame = field(
        default_factory=lambda: schema.empty(schema.TRAFFIC_LIGHT_STATES)
    )
    ego_actor_id: str | None = None
    rows_read: int = 0
    rows_rejected: int = 0
    reject_reason: str | None = None
    attribution: str | None = None
