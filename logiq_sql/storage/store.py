"""Storing a run's outputs in the DuckDB file, one transaction per batch of drives, and reading them back."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core.sql import header, query_text, recount_coverage
from logiq_sql.core.timing import stage
from logiq_sql.spec.plan import run_record
from logiq_sql.spec.scenario import Scenario
from logiq_sql.storage import tables
from logiq_sql.storage.db import stored_schema
from logiq_sql.storage.tables import MATCH_PHASES, MATCHES

# kept in the file for analysts (and for rendered SQL, which reads encroachments), replaced per drive, with the
# file whose header documents their columns
PERSISTED = {"relations": "queries/relations/relations.sql", "ego_lanes": "queries/relations/ego_lanes.sql",
             "passages": "queries/junctions/passages.sql", "encroachments": "logiq_sql/matching/encroachment.py"}
# stored by every run, the rest of PERSISTED only with ``keep`` (match --keep): evaluate reads which egos the
# matcher used from ego_lanes (a row per ego frame), while relations (about twice the track rows), passages and
# encroachments are recomputed on demand (explain, the relations_of table macro)
STORED_ALWAYS = ("ego_lanes",)
ENCROACHMENTS_GRAIN = ("one row per (drive_id, ego_id, actor_id) pair of junction passages whose swept paths share "
                       "an area")
EXPORTED = ("drives", "matches", "match_phases", "kpis", "coverage", "coverage_samples", "match_runs",
            "drive_scenarios")


@dataclass
class ScenarioOutput:
    """What one scenario produced on one batch of drives."""

    scenario: Scenario
    matches: pl.DataFrame
    phases: pl.DataFrame
    kpis: pl.DataFrame
    samples: pl.DataFrame
    buckets: pl.DataFrame
    egos: pl.DataFrame  # drive_id, egos: how many SUTs each drive had


def ensure_kpi_columns(con: duckdb.DuckDBPyConnection, scenarios: list[Scenario]) -> None:
    """The ``kpis`` table with a column for every KPI and coverage value of ``scenarios`` (typed as declared).
    Nothing to do where ``kpis`` is a view over the Parquet of a Spark run (logiq_sql/matching/spark_out.py)."""
    con.execute("create table if not exists kpis (match_id varchar not null, scenario varchar not null)")
    if con.execute("select count(*) from duckdb_views() where view_name = 'kpis' and not temporary").fetchall()[0][0]:
        return
    con.execute("comment on table kpis is 'One row per match: every KPI and sampled coverage value of its scenario, in the spec''s "
                "units (column suffix); NULL where the scenario does not record that KPI or the value is undefined.'")
    con.execute("comment on column kpis.match_id is 'Match (matches.match_id).'")
    con.execute("comment on column kpis.scenario is 'Scenario.'")
    have = {r[0] for r in con.execute(
        "select column_name from duckdb_columns() where table_name = 'kpis'").fetchall()}
    for s in scenarios:
        for column, (_unit, sql_type, doc) in s.metric_columns().items():
            if column not in have:
                con.execute(f"alter table kpis add column {column} {sql_type}")
                tables.comment_column(con, "kpis", column, doc)
                have.add(column)


def store_batch(con: duckdb.DuckDBPyConnection, run_id: str, ego: str, range_m: float, run_drives: pl.DataFrame,
                results: list[ScenarioOutput], keep: bool = False) -> None:
    """Replace the outputs of ``results`` on ``run_drives`` (and the kept relation tables: STORED_ALWAYS, the rest
    of PERSISTED only with ``keep``) in one transaction."""
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    stored = stored_schema(con)  # the run's temp tables shadow the stored ones of the same name
    made = {r[0] for r in con.execute("select table_name from duckdb_tables() where temporary union all "
                                      "select view_name from duckdb_views() where temporary").fetchall()}
    for table in (t for t in PERSISTED if t in made and (keep or t in STORED_ALWAYS)):
        # created empty in a transaction of its own: a DuckDB 2.0 table created and filled in one transaction
        # keeps the empty table's statistics, so filters on it (`where drive_id = ...`, the delete below in a
        # later batch) skipped every row (kept relations were stored twice)
        columns = ("select column_name, data_type from duckdb_columns() where table_name = $t and {} "
                   "order by column_index")
        mine = con.execute(columns.format("database_name = 'temp'"), {"t": table}).fetchall()
        kept = con.execute(columns.format("database_name = current_database() and schema_name = 'main'"),
                           {"t": table}).fetchall()
        if kept and kept != mine:
            # kept by a version whose table had other columns: its rows are intermediate results of other SQL,
            # recomputed by match --keep; inserting into it would mix the two
            con.execute(f"drop table {stored}.{table}")
        con.execute(f"create table if not exists {stored}.{table} as select * from temp.main.{table} limit 0")
    con.execute("begin transaction")
    try:
        have = {r[0] for r in con.execute("select table_name from duckdb_tables() where not temporary").fetchall()}
        for table in (t for t in PERSISTED if t in have and not (keep or t in STORED_ALWAYS)):
            # not kept this run: rows an earlier run kept for these drives would no longer be the last run's
            con.execute(f"delete from {stored}.{table} where drive_id in (select drive_id from run_drives)")
        for table in (t for t in PERSISTED if t in made and (keep or t in STORED_ALWAYS)):
            con.execute(f"delete from {stored}.{table} where drive_id in (select drive_id from run_drives)")
            con.execute(f"insert into {stored}.{table} select * from temp.main.{table}")
            describe_persisted(con, stored, table)
        for out in results:
            s = out.scenario
            # rows that hang off the matches first, then the matches themselves
            for table in ("match_phases", "kpis", "coverage_samples"):
                con.execute(f"delete from {table} where scenario = $s and match_id in (select match_id from matches "
                            "where scenario = $s and drive_id in (select drive_id from run_drives))", {"s": s.name})
            con.execute("delete from matches where scenario = $s and drive_id in (select drive_id from run_drives)",
                        {"s": s.name})
            con.execute("delete from coverage_buckets where scenario = $s", {"s": s.name})
            con.execute("delete from drive_scenarios where scenario = $s and drive_id in "
                        "(select drive_id from run_drives)", {"s": s.name})
            tables.insert(con, "matches", out.matches.with_columns(run_id=pl.lit(run_id)).select(MATCHES.column_names))
            tables.insert(con, "match_phases", out.phases.select(MATCH_PHASES.column_names))
            tables.insert(con, "kpis", out.kpis)
            tables.insert(con, "coverage_samples", out.samples)
            tables.insert(con, "coverage_buckets", out.buckets)
            tables.insert(con, "drive_scenarios",
                      drive_status(con, run_drives, out.matches, out.egos, s).with_columns(run_id=pl.lit(run_id)))
            # one row per run and scenario: a later batch of the same run adds its drives and matches
            (before,) = con.execute(
                "select min(started_at), coalesce(sum(drives), 0), coalesce(sum(matches), 0) from match_runs "
                "where run_id = $r and scenario = $s", {"r": run_id, "s": s.name}).fetchall()
            con.execute("delete from match_runs where run_id = $r and scenario = $s", {"r": run_id, "s": s.name})
            tables.insert(con, "match_runs", pl.DataFrame([run_record(
                s, run_id=run_id, started_at=before[0] or started, ego_mode=ego,
                drives=before[1] + run_drives.height, matches=before[2] + out.matches.height,
                relation_range_m=range_m)], schema=tables.MATCH_RUNS.polars_schema))
        with stage("coverage"):
            recount_coverage(con)
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise


def describe_persisted(con: duckdb.DuckDBPyConnection, stored: str, table: str) -> None:
    """Table and column comments for a kept table, from the header of the file that defines it."""
    source = PERSISTED[table]
    if source.endswith(".sql"):
        found = header(query_text(source.removeprefix("queries/")))
        grain, docs = found.fields["grain"], found.columns
    else:
        grain, docs = ENCROACHMENTS_GRAIN, {}
    tables.comment_derived(con, f"{stored}.{table}", table,
                       f"Kept from the last match run of each drive: {grain} ({source}, docs/semantics.md).",
                       docs, f"See the header of {source} and docs/semantics.md.")


def drive_status(con, run_drives: pl.DataFrame, matches: pl.DataFrame, egos: pl.DataFrame, s: Scenario):
    """Per drive of the run: matched, no_match, no_ego or rejected, with its number of egos and matches."""
    status = con.sql("select drive_id, status from drive_inputs").pl()
    per = matches.group_by("drive_id").agg(pl.len().alias("matches"))
    frame = (
        run_drives.join(status, on="drive_id", how="left")
        .join(egos, on="drive_id", how="left")
        .join(per, on="drive_id", how="left")
        .with_columns(pl.col("egos").fill_null(0), pl.col("matches").fill_null(0).cast(pl.Int64))
    )
    return frame.select(
        "drive_id", pl.lit(s.name).alias("scenario"), pl.lit(s.params_hash()).alias("params_hash"),
        pl.col("egos").cast(pl.Int64), "matches",
        pl.when(pl.col("status") == "rejected").then(pl.lit("rejected"))
        .when(pl.col("egos") == 0).then(pl.lit("no_ego"))
        .when(pl.col("matches") > 0).then(pl.lit("matched"))
        .otherwise(pl.lit("no_match")).alias("status"),
    )


def export(con: duckdb.DuckDBPyConnection, out: str | Path) -> None:
    """Write the output tables as Parquet files in ``out`` (sorted, so reruns give the same files)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for table in EXPORTED:
        frame = con.sql(f"select * from {table}").pl()
        keys = [c for c in ("scenario", "drive_id", "match_id", "item", "bucket_index", "bucket", "run_id",
                            "phase_index") if c in frame.columns]
        frame.sort(keys, nulls_last=True).write_parquet(out / f"{table}.parquet")
