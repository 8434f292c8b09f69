"""The canonical tables: names, columns, types, units and meaning.

This module is the one place where the canonical schema is written down. The DuckDB DDL, the column comments,
the Parquet reader's checks and the docs table in ``docs/tables.md`` are all generated from it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import polars as pl

from logiq_sql.core.formats import FORMATS

# The evaluation_object_kind values of the spec, in the spec's order.
OBJECT_KINDS: tuple[str, ...] = (
    "object", "person", "cyclist", "vehicle", "truck", "trailer", "fod", "animal", "sign", "bus",
    "motorcycle", "emergency_vehicle", "stationary_vehicle",
)
# What a vehicle_actor may be when a scenario's `kinds` parameter is left unset (the spec gives no default).
VEHICLE_KINDS: tuple[str, ...] = ("vehicle", "truck", "bus", "motorcycle", "emergency_vehicle", "trailer")
# the kinds that can be the SUT when --ego-kinds is not given: the vehicle kinds but trailer
EGO_KINDS: tuple[str, ...] = tuple(k for k in VEHICLE_KINDS if k != "trailer")

TRAFFIC_LIGHT_STATES: tuple[str, ...] = ("green", "yellow", "red", "red_yellow", "off", "unknown")


# each column type as DuckDB, Arrow and Spark name it, by its Polars type: the one table the DDL, the Parquet
# dataset's views and the engines read
TYPE_NAMES: dict[type[pl.DataType], tuple[str, str, str]] = {
    pl.String: ("VARCHAR", "string", "StringType"),
    pl.Float64: ("DOUBLE", "float64", "DoubleType"),
    pl.Int64: ("BIGINT", "int64", "LongType"),
    pl.Boolean: ("BOOLEAN", "bool_", "BooleanType"),
}


def duckdb_type(dtype: pl.DataType | type[pl.DataType]) -> str:
    return TYPE_NAMES[dtype if isinstance(dtype, type) else type(dtype)][0]


def arrow_type(dtype: pl.DataType | type[pl.DataType]):
    import pyarrow as pa

    return getattr(pa, TYPE_NAMES[dtype if isinstance(dtype, type) else type(dtype)][1])()


def spark_type(dtype: pl.DataType | type[pl.DataType]):
    from pyspark.sql import types as T

    return getattr(T, TYPE_NAMES[dtype if isinstance(dtype, type) else type(dtype)][2])()


@dataclass(frozen=True)
class Column:
    name: str
    dtype: pl.DataType
    doc: str
    nullable: bool = True


@dataclass(frozen=True)
class Table:
    name: str
    doc: str
    columns: tuple[Column, ...]

    @property
    def polars_schema(self) -> dict[str, pl.DataType]:
        return {c.name: c.dtype for c in self.columns}

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]


S, F, I, B = pl.String(), pl.Float64(), pl.Int64(), pl.Boolean()

TRACKS = Table(
    "tracks",
    "One row per actor per timestamp, in a right-handed map frame (x east, y north), SI units.",
    (
        Column("drive_id", S, "The drive (log, scene, simulation run) this row belongs to.", False),
        Column("actor_id", S, "Tracking id of the actor inside its drive, as the source names it.", False),
        Column("kind", S, f"evaluation_object_kind: one of {', '.join(OBJECT_KINDS)}.", False),
        Column("is_ego", B, "True on the recorded ego (SUT) rows; every row of an ego-less source is False.", False),
        Column("frame", I, "Sample index, t_s / dt_s rounded; consecutive integers mean consecutive samples.", False),
        Column("t_s", F, "Time since the start of the drive, seconds.", False),
        Column("x_m", F, "Centre of the bounding box, metres.", False),
        Column("y_m", F, "Centre of the bounding box, metres.", False),
        Column("heading_rad", F, "Yaw of the box, radians counter-clockwise from +x; derived from motion if absent."),
        Column("speed_mps", F, "Longitudinal speed along the heading, m/s; derived from positions if absent."),
        Column("accel_mps2", F, "Longitudinal acceleration, m/s^2; derived from speed if absent."),
        Column("length_m", F, "Box length along the heading, metres."),
        Column("width_m", F, "Box width across the heading, metres."),
    ),
)

DRIVE_INPUTS = Table(
    "drive_inputs",
    "One row per drive that ingest saw, accepted or rejected, with where it came from.",
    (
        Column("drive_id", S, "Unique id of the drive in this database.", False),
        Column("source_format", S, f"The reader: {', '.join(FORMATS)} (frames: given to match_frames, in "
                               "memory).", False),
        Column("source_path", S, "File the drive was read from.", False),
        Column("map_id", S, "Key into the map tables (lanes, junctions, ...); NULL when the source has no map."),
        Column("dt_s", F, "Sample period in seconds."),
        Column("ego_actor_id", S, "The recorded ego's actor_id; NULL for ego-less sources such as NGSIM."),
        Column("rows_read", I, "Track rows found in the source.", False),
        Column("rows_rejected", I, "Track rows dropped at ingest (see reject_reason).", False),
        Column("status", S, "ingested or rejected.", False),
        Column("reject_reason", S, "Why the drive (or some of its rows) was rejected."),
        Column("attribution", S, "Licence and attribution of the data."),
    ),
)

LANES = Table(
    "lanes",
    "Lanes as polygons in the map frame (WKT), with neighbours and whether they lie in a junction.",
    (
        Column("map_id", S, "Map the lane belongs to.", False),
        Column("lane_id", S, "Lane id inside its map.", False),
        Column("lane_type", S, "Source lane type (e.g. urban, highway, VEHICLE, BIKE)."),
        Column("polygon_wkt", S, "Lane area as a WKT POLYGON.", False),
        Column("centerline_wkt", S, "Centre line as a WKT LINESTRING in driving direction.", False),
        Column("left_lane_id", S, "Left neighbour lane, NULL if none."),
        Column("left_same_direction", B, "True if the left neighbour is driven in the same direction."),
        Column("right_lane_id", S, "Right neighbour lane, NULL if none."),
        Column("right_same_direction", B, "True if the right neighbour is driven in the same direction."),
        Column("speed_limit_mps", F, "Speed limit, m/s, NULL if unknown."),
        Column("junction_id", S, "Junction (intersection) this lane lies in, NULL if none."),
    ),
)

LANE_SUCCESSORS = Table(
    "lane_successors",
    "Directed lane graph: a car at the end of lane_id may continue on successor_id.",
    (
        Column("map_id", S, "Map.", False),
        Column("lane_id", S, "From lane.", False),
        Column("successor_id", S, "To lane.", False),
        Column("turn", S, "left, right, straight or NULL when the source does not say."),
    ),
)

JUNCTIONS = Table(
    "junctions",
    "Junctions (intersections) as the union of their lanes' polygons.",
    (
        Column("map_id", S, "Map.", False),
        Column("junction_id", S, "Junction id.", False),
        Column("polygon_wkt", S, "Junction area as WKT.", False),
    ),
)

TRAFFIC_LIGHTS = Table(
    "traffic_lights",
    "Traffic lights and the lanes they govern.",
    (
        Column("map_id", S, "Map.", False),
        Column("light_id", S, "Light id.", False),
        Column("lane_id", S, "A lane this light governs (one row per lane).", False),
        Column("direction", S, "The movements it governs: a comma-separated subset of left, straight, right, u_turn; "
                           "NULL = every movement from the lane."),
        Column("x_m", F, "Light position, metres (NULL if unknown)."),
        Column("y_m", F, "Light position, metres (NULL if unknown)."),
    ),
)

TRAFFIC_LIGHT_STATES = Table(
    "traffic_light_states",
    "State of every light at every frame of a drive, where the data has it.",
    (
        Column("drive_id", S, "Drive.", False),
        Column("light_id", S, "Light id.", False),
        Column("frame", I, "Sample index.", False),
        Column("state", S, f"One of {', '.join(TRAFFIC_LIGHT_STATES)}.", False),
    ),
)

# Integer keys assigned at ingest: every query joins, windows and groups on them (integers hash and sort several
# times faster than the string ids); drive_id and actor_id stay for people and for the outputs.
DRIVE_KEY = Column("drive_key", I, "Integer key of the drive, assigned at ingest (a 64-bit digest of drive_id, "
                                   "unique in the file): what queries join on.")
TRACK_KEYS = (
    DRIVE_KEY,
    Column("actor_key", I, "Integer key of the actor within its drive, assigned at ingest: its rank in actor_id "
                           "order, from 1."),
    Column("row_key", I, "Integer key of the track row within its drive, assigned at ingest: its rank in "
                         "(actor_id, frame) order, from 1."),
)


def drive_key(drive_id: str) -> int:
    """The drive's integer key: a signed 64-bit digest of its drive_id (the same in every file and dataset)."""
    return int.from_bytes(hashlib.blake2b(drive_id.encode(), digest_size=8).digest(), "big", signed=True)


def with_keys(table: Table, keys: tuple[Column, ...], doc: str) -> Table:
    """``table`` as stored: its columns, then the integer keys ingest assigns."""
    return Table(table.name, f"{table.doc} {doc}", (*table.columns, *keys))


# the tables as stored (readers give TRACKS; ingest adds the keys and stores the rows in (drive, actor, frame) order)
STORED_TRACKS = with_keys(TRACKS, TRACK_KEYS, "Stored in (drive, actor_id, frame) order, with integer keys.")
STORED_DRIVE_INPUTS = with_keys(DRIVE_INPUTS, (DRIVE_KEY,), "drive_key is the integer key of the drive.")

MAP_TABLES = (LANES, LANE_SUCCESSORS, JUNCTIONS, TRAFFIC_LIGHTS)
MAP_TABLE_NAMES = tuple(t.name for t in MAP_TABLES)
ALL_INPUT_TABLES = (STORED_DRIVE_INPUTS, STORED_TRACKS, *MAP_TABLES, TRAFFIC_LIGHT_STATES)


def empty(table: Table) -> pl.DataFrame:
    """An empty frame with the table's schema."""
    return pl.DataFrame(schema=table.polars_schema)

# Box size used when a source gives none (length_m, width_m), by kind; documented in docs/tables.md.
DEFAULT_SIZE_M: dict[str, tuple[float, float]] = {
    "vehicle": (4.5, 1.8), "truck": (8.0, 2.5), "bus": (12.0, 2.5), "trailer": (8.0, 2.5),
    "motorcycle": (2.2, 0.8), "emergency_vehicle": (5.5, 2.0), "stationary_vehicle": (4.5, 1.8),
    "cyclist": (1.8, 0.6), "person": (0.6, 0.6), "animal": (1.0, 0.5),
    "object": (0.5, 0.5), "fod": (0.3, 0.3), "sign": (0.3, 0.3),
}

TRACK_LANES = Table(
    "track_lanes",
    "Every lane within 3 m of every track row (the lane look-up at ingest, docs/localisation.md); scenarios apply "
    "their own tolerance.",
    (
        Column("drive_id", S, "Drive.", False),
        Column("actor_id", S, "Actor.", False),
        Column("frame", I, "Sample index.", False),
        Column("lane_id", S, "A lane of the drive's map.", False),
        Column("dist_m", F, "Distance from the box centre to the lane polygon, 0 inside.", False),
        Column("heading_diff_rad", F,
               "Actor heading minus lane direction at the nearest centre-line point, in (-pi, pi].", False),
    ),
)
# the lane relations/actor_lanes.sql picks for a track row, marked at ingest so that no query ranks a row's lanes
BEST_LANE = Column("best_lane", B, "True on the track row's best lane, false on its others: of its lanes within 90 "
                                   "degrees of its heading (abs(heading_diff_rad) < pi/2), the nearest (dist_m; 0 "
                                   "inside), then the best aligned (least abs(heading_diff_rad)), then the smallest "
                                   "lane_id. Marked at ingest; a scenario's actor lane is this lane when dist_m is "
                                   "within its lane tolerance (relations/actor_lanes.sql).")
STORED_TRACK_LANES = Table(TRACK_LANES.name, f"{TRACK_LANES.doc} Stored in (drive, actor_id, frame) order, with the "
                           "integer keys of its track row and its best lane marked.",
                           (*TRACK_LANES.columns, *TRACK_KEYS, BEST_LANE))
LOCALISATION_RANGE_M = 3.0
# tables whose rows belong to one drive: replaced together when the drive is ingested again or rejected
DRIVE_TABLE_NAMES = ("tracks", "track_lanes", "traffic_light_states", "drive_inputs")
