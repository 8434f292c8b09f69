"""The tables of the DuckDB file: the output tables' schema, the DDL that creates every table and view with a comment
on each column (and adds columns a newer version declares), and appending rows."""

from __future__ import annotations

import duckdb
import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.core.schema import Column, Table, duckdb_type
from logiq_sql.core.sql import registered, sql_literal

S, F, I, B = pl.String(), pl.Float64(), pl.Int64(), pl.Boolean()

MATCHES = Table(
    "matches",
    "One row per match: a scenario, a drive, the ego (SUT) and the actor bound to the scenario's second role.",
    (
        Column("match_id", S, "md5 of scenario, drive, ego, actor and start frame: stable across reruns.", False),
        Column("scenario", S, "Scenario name (file in scenarios/).", False),
        Column("scenario_version", I, "The scenario file's version.", False),
        Column("params_hash", S, "Digest of the bound parameter values (see match_runs.params_json).", False),
        Column("drive_id", S, "Drive.", False),
        Column("ego_id", S, "actor_id of the ego (SUT).", False),
        Column("actor_id", S, "actor_id of the other actor (vehicle_actor, cyclist).", False),
        Column("start_frame", I, "First frame of the match.", False),
        Column("end_frame", I, "Last frame of the match (inclusive).", False),
        Column("start_s", F, "t_s of the first frame.", False),
        Column("end_s", F, "t_s of the last frame.", False),
        Column("duration_s", F, "end_s - start_s.", False),
        Column("run_id", S, "The run that produced the match: join match_runs using (run_id, scenario) for its "
                        "parameter values."),
    ),
)

MATCH_PHASES = Table(
    "match_phases",
    "The interval of every phase of every match.",
    (
        Column("match_id", S, "Match.", False),
        Column("scenario", S, "Scenario.", False),
        Column("phase_index", I, "1 for the first phase.", False),
        Column("phase", S, "Phase name from the spec.", False),
        Column("start_frame", I, "First frame of the phase.", False),
        Column("end_frame", I, "Last frame of the phase.", False),
        Column("start_s", F, "Start, seconds.", False),
        Column("end_s", F, "End, seconds.", False),
    ),
)

COVERAGE_SAMPLES = Table(
    "coverage_samples",
    "One row per (match, coverage item): the sampled value in the item's unit.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("match_id", S, "Match.", False),
        Column("item", S, "Coverage item name from the spec.", False),
        Column("unit", S, "Unit of value_num, or the enum type.", False),
        Column("value_num", F, "Numeric sample; NULL for enum items or undefined values."),
        Column("value_text", S, "Enum sample; NULL for numeric items."),
    ),
)

COVERAGE_BUCKETS = Table(
    "coverage_buckets",
    "The buckets of every coverage item: half-open [lo, hi) in the item's unit, or one enum value.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("item", S, "Coverage item.", False),
        Column("bucket_index", I, "0-based bucket number.", False),
        Column("bucket", S, "Label, e.g. '[10, 20)' or the enum value.", False),
        Column("lo", F, "Lower edge (inclusive), NULL for enum buckets."),
        Column("hi", F, "Upper edge (exclusive), NULL for enum buckets."),
        Column("value_text", S, "Enum value, NULL for numeric buckets."),
    ),
)

COVERAGE = Table(
    "coverage",
    "Coverage histograms over every match in the file: one row per bucket (empty ones too), plus 'out_of_range' "
    "and 'missing' rows where samples fell outside every bucket or were undefined.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("item", S, "Coverage item.", False),
        Column("bucket_index", I, "Bucket number; NULL for out_of_range and missing."),
        Column("bucket", S, "Bucket label, 'out_of_range' or 'missing'.", False),
        Column("lo", F, "Lower edge (inclusive)."),
        Column("hi", F, "Upper edge (exclusive)."),
        Column("hits", I, "Matches whose sample fell in the bucket.", False),
    ),
)

MATCH_RUNS = Table(
    "match_runs",
    "One row per (run, scenario): the parameter values used, so every match can be rerun.",
    (
        Column("run_id", S, "Run id (time-ordered).", False),
        Column("started_at", S, "UTC start time, ISO 8601.", False),
        Column("scenario", S, "Scenario.", False),
        Column("scenario_version", I, "Scenario file version.", False),
        Column("params_hash", S, "Digest of params_json.", False),
        Column("params_json", S, "Every SQL parameter and its bound value, canonical units.", False),
        Column("overrides", S, "The --set values as written.", False),
        Column("ego_mode", S, "auto, recorded, all, every:N or an actor id.", False),
        Column("drives", I, "Drives matched in the run (drives already up to date are not rerun, see drive_scenarios).",
           False),
        Column("matches", I, "Matches found on those drives.", False),
        Column("relation_range_m", F, "The --relation-range of the run, metres."),
        Column("queries_hash", S, "Digest of the text of every query the scenario's run executed: a later run "
               "reruns a drive whose latest run had another (an edited query), whatever the scenario version."),
    ),
)

DRIVE_SCENARIOS = Table(
    "drive_scenarios",
    "One row per (drive, scenario) of the latest run of that scenario over that drive. A later run skips the pair "
    "while its run had the same params_hash, queries_hash, ego_mode and relation_range_m (match --force reruns "
    "it); re-ingesting "
    "the drive removes its rows.",
    (
        Column("drive_id", S, "Drive.", False),
        Column("scenario", S, "Scenario.", False),
        Column("params_hash", S, "Parameters of that run.", False),
        Column("egos", I, "SUTs considered in the drive.", False),
        Column("matches", I, "Matches found.", False),
        Column("status", S, "matched, no_match, no_ego (no actor could be the SUT) or rejected.", False),
        Column("run_id", S, "The run that matched the pair: join match_runs using (run_id, scenario)."),
    ),
)

INGEST_VERSIONS = Table(
    "ingest_versions",
    "One row per drive written by ingest: a version that changes whenever the drive's rows or its map's rows are "
    "written again. The step cache (step_cache) trusts an entry only for the version it was computed from.",
    (
        Column("drive_id", S, "Drive (drive_inputs.drive_id).", False),
        Column("ingest_version", S, "A fresh random id per ingest of the drive, or of another drive on its map.",
               False),
    ),
)

STEP_CACHE_PREFIX = "step_cache_"
STEP_CACHE = Table(
    "step_cache",
    "The step cache's index (logiq_sql/storage/step_cache.py), in the cache's own file <file>.step_cache: one row "
    "per (scenario, step, drive) whose step output is kept in the table step_cache_<key> of that file. A step's key "
    "is a digest of its query text, the values it binds, the keys of the step tables it reads and the DuckDB "
    "version; an entry is read only while the drive's ingest version is the one it was computed from. Re-ingesting "
    "a drive drops its entries.",
    (
        Column("scenario", S, "A scenario whose run used the entry: each scenario keeps its latest entry per step.",
               False),
        Column("step", S, "The step table and its query file, e.g. 'phase_1 phases/ego_follows_actor.sql'.", False),
        Column("drive_id", S, "Drive.", False),
        Column("step_key", S, "Digest of the step's query text, bound values and inputs (see the table comment).",
               False),
        Column("table_name", S, "The table holding the step's rows (of every drive with this key).", False),
        Column("ingest_version", S, "ingest_versions.ingest_version of the drive when the step was computed.", False),
    ),
)

OUTPUT_TABLES = (MATCHES, MATCH_PHASES, COVERAGE_SAMPLES, COVERAGE_BUCKETS, COVERAGE, MATCH_RUNS, DRIVE_SCENARIOS)
TABLES = (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES, INGEST_VERSIONS, *OUTPUT_TABLES)  # in the file


DRIVES_VIEW = """
create or replace view drives as
select
    d.drive_id,
    d.source_format,
    d.source_path,
    d.map_id,
    d.dt_s,
    d.ego_actor_id,
    d.rows_read,
    d.rows_rejected,
    d.reject_reason,
    case
        when d.status = 'rejected' then 'rejected'
        when count(s.scenario) = 0 then 'not_matched'
        when sum(s.matches) > 0 then 'matched'
        when bool_and(s.status = 'no_ego') then 'no_ego'
        else 'no_match'
    end as status,
    cast(coalesce(sum(s.matches), 0) as bigint) as matches,
    string_agg(s.scenario || '=' || cast(s.matches as varchar), ', ' order by s.scenario) as matches_per_scenario
from drive_inputs as d
left join drive_scenarios as s
    on d.drive_id = s.drive_id
group by
    d.drive_id, d.source_format, d.source_path, d.map_id, d.dt_s, d.ego_actor_id, d.rows_read,
    d.rows_rejected, d.reject_reason, d.status
"""
DRIVES_DOC = {
    "status": "rejected, matched (any scenario matched), no_match, no_ego, or not_matched (no run yet).",
    "matches": "Matches over every scenario run on the drive.",
    "matches_per_scenario": "scenario=count, for every scenario run on the drive.",
}


def comment_column(con: duckdb.DuckDBPyConnection, table: str, column: str, doc: str) -> None:
    """Store ``doc`` as the DuckDB comment of ``table.column`` (names are ours, the text is quoted)."""
    con.execute(f"comment on column {table}.{column} is {sql_literal(doc)}")


def create_table(con: duckdb.DuckDBPyConnection, table: Table, extra: tuple[Column, ...] = (),
                 catalog: str | None = None) -> None:
    """``table`` in the file (or in the attached database ``catalog``), created where missing, new columns added."""
    columns = (*table.columns, *extra)
    name = table.name if catalog is None else f"{catalog}.main.{table.name}"
    cols = ",\n    ".join(
        f"{c.name} {duckdb_type(c.dtype)}{'' if c.nullable else ' NOT NULL'}" for c in columns
    )
    con.execute(f"create table if not exists {name} (\n    {cols}\n)")
    # a file written by an earlier version gains the nullable columns added since (NULL in its old rows)
    have = {r[0] for r in con.execute(
        "select column_name from duckdb_columns() where table_name = $t and schema_name = 'main' "
        "and database_name = coalesce($c, current_database())", {"t": table.name, "c": catalog}).fetchall()}
    for c in columns:
        if c.name not in have and c.nullable:
            con.execute(f"alter table {name} add column {c.name} {duckdb_type(c.dtype)}")
    con.execute(f"comment on table {name} is {sql_literal(table.doc)}")
    for c in columns:
        con.execute(f"comment on column {name}.{c.name} is {sql_literal(c.doc)}")


# columns that mean the same in every derived table
KEY_DOCS = {
    "drive_id": "Drive.", "ego_id": "actor_id of the ego (SUT).", "actor_id": "Actor (tracks.actor_id).",
    "frame": "Sample index.", "t_s": "Time since the start of the drive, seconds.",
    "map_id": "Map.", "junction_id": "Junction.",
}


def comment_derived(con: duckdb.DuckDBPyConnection, qualified: str, name: str, doc: str,
                    column_docs: dict[str, str], fallback: str) -> None:
    """Comment a table the matcher derives (relations, ...): its columns from ``column_docs``, the shared keys,
    else ``fallback`` (where the definition is)."""
    con.execute(f"comment on table {qualified} is {sql_literal(doc)}")
    columns = con.execute("select column_name from duckdb_columns() where table_name = $t and schema_name = 'main' "
                          "and database_name = current_database()", {"t": name}).fetchall()
    for (col,) in columns:
        text = column_docs.get(col) or KEY_DOCS.get(col) or fallback
        con.execute(f"comment on column {qualified}.{col} is {sql_literal(text)}")


def create_all(con: duckdb.DuckDBPyConnection) -> None:
    """Every table and the drives view, with their comments: created where missing, new columns added."""
    for table in TABLES:
        create_table(con, table)
    # a file written before the step cache moved to a file of its own kept it inside: nothing reads it any more
    for (name,) in con.execute(
            "select table_name from duckdb_tables() where database_name = current_database() and schema_name = 'main' "
            "and (table_name = $i or starts_with(table_name, $p))",
            {"i": STEP_CACHE.name, "p": STEP_CACHE_PREFIX}).fetchall():
        con.execute(f"drop table {name}")
    backfill_keys(con)
    backfill_best_lanes(con)
    con.execute(DRIVES_VIEW)
    con.execute("comment on view drives is " + sql_literal(
        "Every drive that went in, accepted or rejected, with its match status over all scenarios run."))
    inherited = {c.name: c.doc for c in schema.DRIVE_INPUTS.columns}
    for (col,) in con.execute("select column_name from duckdb_columns() where table_name = 'drives'").fetchall():
        con.execute(f"comment on column drives.{col} is {sql_literal(DRIVES_DOC.get(col) or inherited[col])}")


def backfill_keys(con: duckdb.DuckDBPyConnection) -> None:
    """A file written before ingest assigned integer keys gets them for its rows (the queries join on them)."""
    drives = [r[0] for r in con.execute("select drive_id from drive_inputs where drive_key is null").fetchall()]
    if not drives:
        return
    keys = pl.DataFrame({"drive_id": drives, "drive_key": [schema.drive_key(d) for d in drives]})
    with registered(con, "_keys", keys):
        con.execute("update drive_inputs as d set drive_key = k.drive_key from _keys as k "
                    "where d.drive_id = k.drive_id")
        con.execute("""
            update tracks as t set drive_key = k.drive_key, actor_key = k.actor_key, row_key = k.row_key
            from (
                select r.drive_id, r.actor_id, r.frame, n.drive_key,
                    dense_rank() over (partition by r.drive_id order by r.actor_id) as actor_key,
                    row_number() over (partition by r.drive_id order by r.actor_id, r.frame) as row_key
                from tracks as r inner join _keys as n on r.drive_id = n.drive_id
            ) as k
            where t.drive_id = k.drive_id and t.actor_id = k.actor_id and t.frame = k.frame""")
        con.execute("""
            update track_lanes as l set drive_key = t.drive_key, actor_key = t.actor_key, row_key = t.row_key
            from tracks as t
            where l.drive_key is null and l.drive_id = t.drive_id and l.actor_id = t.actor_id and l.frame = t.frame""")


def backfill_best_lanes(con: duckdb.DuckDBPyConnection) -> None:
    """A file written before ingest marked each track row's best lane gets it marked (schema.BEST_LANE, the order
    relations/actor_lanes.sql ranked the lanes in before)."""
    if not con.execute("select count(*) from (select 1 from track_lanes where best_lane is null limit 1)").fetchone()[0]:
        return
    con.execute("""
        update track_lanes as l set best_lane = coalesce(r.rank_in_row = 1, false)
        from (
            select drive_key, row_key, lane_id, case when abs(heading_diff_rad) < pi() / 2 then row_number() over (
                partition by drive_key, row_key, abs(heading_diff_rad) < pi() / 2
                order by dist_m, abs(heading_diff_rad), lane_id) end as rank_in_row
            from track_lanes
            where best_lane is null
        ) as r
        where l.best_lane is null and l.drive_key = r.drive_key and l.row_key = r.row_key and l.lane_id = r.lane_id""")


def outdated(con: duckdb.DuckDBPyConnection, path: object) -> str | None:
    """What a file written by an earlier logiq_sql, that no run has opened for writing since, lacks, and the fix;
    None for a current file. A read-only connection cannot add the input columns added since (create_all does,
    with their values)."""
    have = set(con.execute("select table_name, column_name from duckdb_columns() where schema_name = 'main' "
                           "and database_name = current_database()").fetchall())
    tables_in_file = {name for name, _ in have}
    missing = [f"{t.name}.{c.name}" for t in (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES)
               if t.name in tables_in_file for c in t.columns if (t.name, c.name) not in have]
    if not missing:
        return None
    return (f"{path}: written by an earlier logiq_sql, it has no column {', '.join(missing)}. Fix: let a run that "
            f"writes the file add {'them' if len(missing) > 1 else 'it'} (`logiq-sql match --db {path}`), then run "
            "this again.")


def require_current(con: duckdb.DuckDBPyConnection, path: object) -> None:
    """Refuse, naming the fix, a file written by an earlier logiq_sql that no run has opened for writing since."""
    if problem := outdated(con, path):
        raise InputError(problem)


def insert(con: duckdb.DuckDBPyConnection, table: str, frame: pl.DataFrame) -> None:
    """Append a Polars frame to a table by column name."""
    if frame.is_empty():
        return
    cols = ", ".join(frame.columns)
    with registered(con, "_frame_to_insert", frame):
        con.execute(f"insert into {table} ({cols}) select {cols} from _frame_to_insert")
