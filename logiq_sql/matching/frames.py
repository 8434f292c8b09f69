"""Match scenarios on tracks held in Polars or Arrow frames, in memory: no file is read or written.

    import logiq_sql as lq

    result = lq.match_frames(tracks, lanes=lanes, lane_successors=successors)   # frames in the canonical layout
    result.matches, result.kpis, result.coverage, result.drives, result.scenarios

The frames go through the same steps as ``ingest parquet`` followed by ``match``: the Parquet reader's column
checks and drive split (``readers/parquet.read_drives``), ingest's row checks, kinematics and localisation
(``ingestion.write_drives``), then the matcher, all on an in-memory DuckDB database that is gone when the call
returns. So the messages, the accounting of every drive and the matches are those of the file route.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import dataclass, field

import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.core.sql import cte_names, tables_read
from logiq_sql.ingestion.ingest import BATCH_ROWS, write_drives
from logiq_sql.ingestion.readers.parquet import check_table, check_track_columns, drive_metadata, read_drives
from logiq_sql.matching.match import MatchResult, match
from logiq_sql.spec.plan import DEFAULT_RELATION_RANGE, phase_steps, resolve_scenarios
from logiq_sql.spec.scenario import Scenario
from logiq_sql.storage import db

SOURCE_FORMAT = "frames"
MAP_INPUTS = (*schema.MAP_TABLES, schema.TRAFFIC_LIGHT_STATES)
# A scenario whose own steps (phases, match, KPIs) read one of these tables cannot find anything without the
# inputs it is built from; every other table a step reads comes from the tracks alone.
BUILT_FROM = {
    **{t: ("lanes",) for t in ("lanes", "lane_successors", "track_lanes", "actor_lanes", "ego_lanes", "ego_road",
                               "lane_line", "lane_neighbours")},
    **{t: ("lanes", "junctions") for t in ("junctions", "passages", "junction_frames", "crossing_pairs")},
    "traffic_lights": ("traffic_lights",),
    "traffic_light_states": ("traffic_light_states",),
}


@dataclass
class FramesResult(MatchResult):
    """``MatchResult`` (matches, match_phases, kpis, coverage, drives) plus, per scenario asked for, whether it ran
    and why not, and the status of every (drive, scenario) pair."""

    scenarios: pl.DataFrame = field(default_factory=pl.DataFrame)
    drive_scenarios: pl.DataFrame = field(default_factory=pl.DataFrame)


def as_lazy(frame: object, name: str) -> pl.LazyFrame:
    """A Polars DataFrame or LazyFrame, or an Arrow table or record batch, as a LazyFrame."""
    if isinstance(frame, pl.LazyFrame):
        return frame
    if isinstance(frame, pl.DataFrame):
        return frame.lazy()
    try:
        import pyarrow as pa
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        pa = None
    if pa is not None and isinstance(frame, pa.Table | pa.RecordBatch):
        return pl.from_arrow(frame).lazy()
    raise InputError(f"{name}: a {type(frame).__name__} is not a table. Fix: pass a Polars DataFrame or LazyFrame or "
                     "an Arrow table, in the canonical columns of docs/tables.md.")


def missing_inputs(s: Scenario, given: set[str]) -> str | None:
    """Why scenario ``s`` cannot run on the inputs ``given`` (the map tables that have rows), or None."""
    lacking: dict[str, None] = {}
    reads: dict[str, list[str]] = {}  # query file -> the tables it reads that lack an input
    for relative in [rel for _, rel in phase_steps(s)] + list(s.kpi_queries):
        for table in sorted(tables_read(relative) - cte_names(relative)):
            absent = [name for name in BUILT_FROM.get(table, ()) if name not in given]
            if absent:
                lacking.update(dict.fromkeys(absent))
                sources = BUILT_FROM[table]
                reads.setdefault(relative, []).append(
                    table if sources == (table,) else f"{table} (built from {' and '.join(sources)})")
    if not lacking:
        return None
    because = "; ".join(f"queries/{rel} reads {', '.join(tables)}" for rel, tables in reads.items())
    return (f"{s.name} cannot run without {', '.join(lacking)}: {because}. Fix: pass "
            f"{', '.join(f'{name}=' for name in lacking)} to match_frames (columns in docs/tables.md).")


def match_frames(tracks: object, *, drives: object = None, lanes: object = None, lane_successors: object = None,
                 junctions: object = None, traffic_lights: object = None, traffic_light_states: object = None,
                 scenarios: list[str] | None = None, overrides: dict[str, str] | None = None, ego: str = "auto",
                 relation_range: str = DEFAULT_RELATION_RANGE,
                 progress: Callable[[str], None] | None = None) -> FramesResult:
    """Check, localise and match drives given as frames, in memory; the results as Polars frames.

    Args:
        tracks: track rows in the canonical columns (required: drive_id, actor_id, kind, t_s, x_m, y_m; optional:
            is_ego, frame, heading_rad, speed_mps, accel_mps2, length_m, width_m), as for ``ingest parquet``.
        drives: optional, one row per drive: drive_id and any of dt_s, map_id, ego_actor_id, attribution.
            Without it (or without a map_id) a drive is on the map of ``lanes`` when that holds one map.
        lanes, lane_successors, junctions, traffic_lights, traffic_light_states: the map tables and light states
            (docs/tables.md); leave them out and the scenarios that need them say why in ``result.scenarios``.
        scenarios, overrides, ego, relation_range, progress: as for ``match``.

    Each frame may be a Polars DataFrame or LazyFrame or an Arrow table. A missing or mistyped column raises
    InputError naming it and the fix (the messages of ``ingest``); a drive that fails a check is rejected and
    listed in ``result.drives`` with the reason; dropped rows are counted there.
    """
    lazy = as_lazy(tracks, "tracks")
    check_track_columns(dict(lazy.collect_schema()), "tracks")
    maps = {t.name: check_table(as_lazy(frame, t.name).collect(), t, t.name)
            for t, frame in zip(MAP_INPUTS, (lanes, lane_successors, junctions, traffic_lights, traffic_light_states),
                                strict=True) if frame is not None}
    meta = drive_metadata(as_lazy(drives, "drives").collect(), "drives") if drives is not None else {}
    _default_map(lazy, meta, maps)

    name = f":memory:logiq_frames_{uuid.uuid4().hex}"  # shared by the connections of this call, then gone
    con = db.connect(name)
    try:
        batch, rows = [], 0
        for drive in read_drives(lazy, meta, maps, "tracks", "drives", SOURCE_FORMAT):
            batch.append(drive)
            rows += drive.tracks.height
            if rows >= BATCH_ROWS:  # bounded memory, as ingest
                write_drives(con, batch)
                batch, rows = [], 0
        write_drives(con, batch)

        chosen = resolve_scenarios(scenarios, overrides or {})  # unknown names and parameters fail here
        given = {t for t, frame in maps.items() if frame.height}
        reasons = {s.name: missing_inputs(s, given) for s in chosen}
        runnable = [s for s in chosen if reasons[s.name] is None]
        if runnable:
            known = {p for s in runnable for p in s.params}
            result = match(name, scenarios=[s.name for s in runnable], ego=ego, relation_range=relation_range,
                           overrides={k: v for k, v in (overrides or {}).items() if k in known}, progress=progress)
        else:
            result = _nothing_ran(con)
        return FramesResult(
            matches=result.matches, match_phases=result.match_phases, kpis=result.kpis, coverage=result.coverage,
            drives=con.sql("select * from drives order by drive_id").pl(),
            scenarios=pl.DataFrame({"scenario": [s.name for s in chosen],
                                    "ran": [reasons[s.name] is None for s in chosen],
                                    "reason": [reasons[s.name] for s in chosen]},
                                   schema={"scenario": pl.String, "ran": pl.Boolean, "reason": pl.String}),
            drive_scenarios=con.sql("select * exclude (run_id) from drive_scenarios "
                                    "order by scenario, drive_id").pl(),
        )
    finally:
        con.close()


def _default_map(lazy: pl.LazyFrame, meta: dict[str, dict], maps: dict[str, pl.DataFrame]) -> None:
    """Drives that ``drives`` gives no map_id are on the map of ``lanes`` when it holds one map; with several maps
    each drive must say which."""
    if "lanes" not in maps:
        return
    map_ids = maps["lanes"]["map_id"].unique().sort().to_list()
    ids = lazy.select(pl.col("drive_id").cast(pl.String).unique().sort()).collect()["drive_id"]
    without = [d for d in ids.drop_nulls() if not meta.get(d, {}).get("map_id")]
    if not without or not map_ids:
        return
    if len(map_ids) > 1:
        raise InputError(f"lanes: holds {len(map_ids)} maps ({', '.join(map_ids[:5])}) and drive '{without[0]}' does "
                         "not say which it is on. Fix: pass drives= with a map_id for every drive.")
    for d in without:
        meta[d] = {**meta.get(d, {"drive_id": d}), "map_id": map_ids[0]}


def _nothing_ran(con) -> MatchResult:
    """Empty results in the stored columns, for a call in which no scenario could run."""
    def empty(table: str) -> pl.DataFrame:
        return con.sql(f"select * from {table} limit 0").pl()

    return MatchResult(matches=empty("matches"), match_phases=empty("match_phases"),
                       kpis=pl.DataFrame(schema={"match_id": pl.String, "scenario": pl.String}),
                       coverage=empty("coverage"), drives=empty("drives"))
