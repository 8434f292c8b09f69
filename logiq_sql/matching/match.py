"""Match scenarios against the drives in a DuckDB file: the orchestration of a run.

    plan (logiq_sql.spec.plan)      scenarios, overrides, SUT choice, the values to bind, the steps in order
    run (logiq_sql.matching.runner)     relations, then per scenario its phases, matches, KPIs and coverage samples
    store (logiq_sql.storage.store)    one transaction per batch of drives; the outputs read back as Polars frames

A run is incremental: a (drive, scenario) pair whose latest run had the same params_hash (scenario version and
every bound value), queries_hash (the text of every query it runs), ego mode and relation range is skipped
(``force`` reruns it). The rest is matched and replaces that scenario's outputs on those drives in one transaction
per batch of drives (MATCH_BATCH_ROWS), so memory stays bounded and an interrupted run keeps the batches it
finished and the previous results of the rest. While a batch runs, its queries read only its drives' rows of
tracks, track_lanes and traffic_light_states (``Engine.select_drives``), so a batch costs what its drives hold,
whatever the file holds.
"""

from __future__ import annotations

import contextlib
import datetime as dt
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core.batching import batches
from logiq_sql.core.errors import ScenarioError, arg, did_you_mean
from logiq_sql.core.sql import drop_temp, registered, render_steps
from logiq_sql.engines import check_engine, open_engine
from logiq_sql.engines.spark_engine import render_for_engine
from logiq_sql.matching import relations_of
from logiq_sql.matching.runner import prepare_relations, run_scenario, shared_phase_steps
from logiq_sql.spec.plan import (
    ALL_KINDS_CSV,
    DEFAULT_RELATION_RANGE,
    ego_key,
    parse_ego,
    queries_hash,
    relation_kinds_csv,
    relation_range_m,
    relation_settings,
    resolve_scenarios,
    run_values,
    scenario_queries,
)

# names callers import from here, kept since match.py was split into plan / runner / store
from logiq_sql.spec.plan import phase_steps as phase_steps  # noqa: F401
from logiq_sql.spec.plan import scenario_steps as scenario_steps  # noqa: F401
from logiq_sql.spec.scenario import Scenario, ScenarioPath
from logiq_sql.storage import db
from logiq_sql.storage import step_cache as cache_file
from logiq_sql.storage.step_cache import StepCache
from logiq_sql.storage.store import EXPORTED as EXPORTED  # noqa: F401
from logiq_sql.storage.store import PERSISTED, ensure_kpi_columns, export, store_batch

# drives are matched in batches of about this many track rows, each stored in its own transaction: memory stays
# bounded whatever the file holds (one pass over every drive of a large file runs out of DuckDB's memory limit;
# benchmarks/README.md, "Figures behind the code's comments")
MATCH_BATCH_ROWS = 2_000_000
# when Spark writes the results itself nothing of a batch is held on the driver and the executors spill: batches
# only bound a killed run's loss, while every batch pays Spark's fixed cost per step (a job per checkpointed
# step), so they are much larger
SPARK_RESULTS_BATCH_ROWS = 100_000_000


@dataclass
class MatchResult:
    """What one run produced, as Polars frames (the file holds the same, plus earlier runs)."""

    matches: pl.DataFrame
    match_phases: pl.DataFrame
    kpis: pl.DataFrame
    coverage: pl.DataFrame
    drives: pl.DataFrame
    up_to_date: dict[str, int] = field(default_factory=dict)  # scenario -> drives skipped as already matched
    cache: str = ""  # what the step cache did in the run and its size afterwards (logiq_sql/storage/step_cache.py)
    cache_steps: list = field(default_factory=list)  # StepCache.steps: each cached step, reused or computed

    def summary(self) -> str:
        lines = []
        skipped = {s: n for s, n in self.up_to_date.items() if n}
        if skipped:
            lines.append("already up to date (same scenario version, parameters, ego and range; --force reruns): "
                         + ", ".join(f"{s} {n} drive(s)" for s, n in sorted(skipped.items())))
        counts = self.drives["status"].value_counts(sort=True) if not self.drives.is_empty() else None
        lines.append(f"drives: {self.drives.height}" + (
            " (" + ", ".join(f"{r['status']} {r['count']}" for r in counts.iter_rows(named=True)) + ")"
            if counts is not None else ""))
        if self.matches.is_empty():
            lines.append("matches: none")
        else:
            per = self.matches.group_by("scenario").agg(
                pl.len().alias("matches"), pl.col("drive_id").n_unique().alias("drives"),
                pl.col("duration_s").mean().alias("mean_s"))
            for r in per.sort("scenario").iter_rows(named=True):
                lines.append(f"  {r['scenario']}: {r['matches']} matches in {r['drives']} drive(s), "
                             f"mean duration {r['mean_s']:.1f} s")
        if self.cache:
            lines.append(self.cache)
        return "\n".join(lines)


def match(db_path: str | Path, *, scenarios: list[str] | None = None, ego: str = "auto",
          overrides: dict[str, str] | None = None, drives: list[str] | None = None,
          relation_range: str = DEFAULT_RELATION_RANGE, out: str | Path | None = None,
          progress: Callable[[str], None] | None = None, force: bool = False, engine: str = "duckdb",
          spark_master: str | None = None, spark_tables: str | Path | None = None,
          batch_rows: int | None = None, scenario_path: ScenarioPath = None,
          ego_kinds: str | None = None, wait_s: float = 0.0, keep: bool = False,
          results: str | Path | None = None, step_cache: str | None = None) -> MatchResult:
    """Match scenarios against the drives in ``db_path`` and store matches, KPIs and coverage there.

    Args:
        db_path: a DuckDB file written by ``ingest``.
        scenarios: scenario names (default: every concrete scenario in ``scenarios/``).
        ego: ``auto`` (recorded ego, else every actor of an ego kind), ``recorded``, ``all``, ``every:N`` or
            actor ids (comma-separated).
        overrides: parameter name -> value with unit, e.g. ``{"max_distance_from_cyclist": "4m"}``.
        drives: restrict the run to these drive ids (default: every ingested drive).
        relation_range: keep ego-actor pairs whose centres are at most this far apart.
        out: also write every output table as Parquet into this folder.
        progress: called with one line per step.
        force: rerun (drive, scenario) pairs that are already up to date.
        engine: ``duckdb`` (default), ``spark`` or ``polars``: what runs the query files (docs/engines.md); the
            results are stored in ``db_path`` the same way whatever the engine.
        spark_master: Spark master URL for ``engine="spark"`` (default: $SPARK_MASTER, else ``local[2]``).
        spark_tables: folder the canonical tables are written to as Parquet for Spark (default: a temporary one).
        batch_rows: match the drives in batches of about this many track rows (a drive is never split); each
            batch is stored in its own transaction, so a killed run keeps the batches it finished (in its copy of
            the file, taken up by the next run). Default MATCH_BATCH_ROWS; SPARK_RESULTS_BATCH_ROWS when Spark
            writes the results itself (``results``).
        wait_s: how long to wait for another run writing the file (``db.open_for_write``; the results are
            published to readers when the run completes).
        scenario_path: a folder of the user's own scenarios (and their SQL), besides the built-in ones.
        ego_kinds: the kinds that can be under test for ``auto``, ``all`` and ``every:N``, comma-separated
            (default vehicle, truck, bus, motorcycle, emergency_vehicle).
        keep: also store the intermediate tables relations, passages and encroachments for analysts (ego_lanes
            is always stored); without it, any such rows an earlier run kept for these drives are removed. The
            kept relations holds the actors of the kinds some scenario of the run can use (``relation_kinds``;
            every kind unless each scenario declares it): a subset of the full relation, which the
            ``relations_of(drive_id, ego_id)`` table macro gives.
        results: with ``engine="spark"``: Spark writes the outputs itself as Parquet partitioned by scenario and
            drive under this folder (logiq_sql/matching/spark_out.py), and ``db_path`` gets views over them; nothing of
            the results passes through the driver.
        step_cache: what the step cache beside the file keeps for later runs (DuckDB engine; docs/operations.md,
            "The step cache"): ``auto`` the steps that cost more to compute than to keep, ``all`` every step, ``off``
            none, and none is read either. Default: $LOGIQ_SQL_STEP_CACHE, else ``auto``.
    """
    say = progress or (lambda _msg: None)
    chosen = resolve_scenarios(scenarios, overrides or {}, scenario_path)
    ego_values = parse_ego(ego, ego_kinds)
    ego = ego_key(ego, ego_kinds)
    range_m = relation_range_m(relation_range)
    mode = cache_file.mode(step_cache)  # checked before the file is copied for the run
    if batch_rows is None:
        batch_rows = SPARK_RESULTS_BATCH_ROWS if results is not None else MATCH_BATCH_ROWS
    if results is not None and engine != "spark":
        raise ScenarioError(f"{arg('engine', engine)}: results written as a Parquet dataset need the spark "
                            "engine; with another engine the results go into the DuckDB file (and --out exports them).")
    with db.open_for_write(db_path, wait_s, say) as con, contextlib.ExitStack() as cleanup:
        run_drives = select_run_drives(con, drives)
        check_engine(engine, [rel for s in chosen for rel in scenario_queries(s)])
        # the step cache (DuckDB engine only; a named in-memory database of match_frames has nothing to keep it
        # for): force recomputes every step, and still keeps what it computed
        cache = None
        if engine == "duckdb" and mode != "off" and not str(db_path).startswith(":memory:"):
            cache_file.attach(con, db_path)  # <file>.step_cache, beside the file (created on first use)
            cache = StepCache(con, read=not force, keep_all=mode == "all")
        runner = open_engine(engine, con, spark_master, None if spark_tables is None else str(spark_tables), cache)
        cleanup.callback(runner.close)
        relations_of.install(con)  # the relation of any ego on demand, since relations is kept only with keep
        run_id = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S%fZ")
        ensure_kpi_columns(con, chosen)
        writer = None
        if results is not None:
            from logiq_sql.matching.spark_out import SparkResults

            writer = SparkResults(runner, results, run_id, ego, range_m, keep)
        # scenarios that share the relation settings and the drives still to match share their relations
        groups: dict[tuple[tuple[float, float], tuple[str, ...]], list[Scenario]] = {}
        up_to_date: dict[str, int] = {}
        for s in chosen:
            todo = run_drives if force else drives_to_match(con, s, run_drives, ego, range_m)
            up_to_date[s.name] = run_drives.height - todo.height
            if todo.height:
                groups.setdefault((relation_settings(s), tuple(todo["drive_id"])), []).append(s)
        work = [(settings, batch, group) for (settings, ids), group in sorted(groups.items())
                for batch in match_batches(con, ids, batch_rows)]
        for step, ((tolerance, _closing), batch, group) in enumerate(work, 1):
            todo = pl.DataFrame({"drive_id": batch}, schema={"drive_id": pl.String})
            with registered(con, "run_drives", todo):
                if runner.name != "duckdb":  # the DuckDB engine reads the registered frame directly
                    runner.register("run_drives", todo)
                say(f"[{step}/{len(work)}] {len(batch)} drive(s): {', '.join(s.name for s in group)}")
                for table in PERSISTED:  # a group keeps only the tables it computes, for its own drives
                    drop_temp(con, table)
                runner.select_drives()
                values = {s.name: run_values(s, ego_values, range_m) for s in group}
                prepare_relations(runner, group, values[group[0].name])
                kinds = relation_kinds_csv(group)
                say(f"  relations: {runner.frame('select count(*) as n from relations')['n'][0]:,} ego-actor rows "
                    f"(lane tolerance {tolerance:g} m"
                    + ("" if kinds == ALL_KINDS_CSV else f"; actors of kinds {kinds.strip(',')} only") + ")")
                if writer is not None:
                    found = writer.write_batch(group, values, batch)
                    for name, n in found.items():
                        say(f"  {name}: {n} matches")
                    runner.forget(tuple(PERSISTED))
                    runner.release_drives()
                    continue
                outputs = []
                runner.share(shared_phase_steps(group, values))
                for s in group:
                    outputs.append(run_scenario(runner, s, values[s.name]))
                    say(f"  {s.name}: {outputs[-1].matches.height} matches")
                runner.persist(tuple(PERSISTED))
                runner.release_drives()
                store_batch(con, run_id, ego, range_m, todo, outputs, keep)
        if writer is not None:
            writer.finish(con)
        result = read_result(con, run_drives, [s.name for s in chosen])
        result.up_to_date = up_to_date
        if cache is not None:
            kept = cache_file.size(con, storage=False)  # bytes count once published: `logiq-sql cache` says them
            result.cache = f"{cache.summary()}; {kept['rows']:,} rows kept in {kept['tables']} table(s)"
            result.cache_steps = cache.steps
        if out is not None:
            export(con, out)
        return result


def match_dataset(dataset: str | Path, out: str | Path, db_path: str | Path | None = None, *, engine: str = "duckdb",
                  wait_s: float = 0.0, progress: Callable[[str], None] | None = None, **kwargs) -> MatchResult:
    """Match a Parquet dataset (``ingest --dataset``): the results file ``db_path`` (default ``out/logiq.duckdb``)
    gets views over the dataset, and the results go to ``out``: with ``engine="spark"`` Spark writes them itself
    as Parquet there (logiq_sql/matching/spark_out.py) and the file gets views over them; with another engine they are
    stored in the file and exported to ``out``. ``kwargs`` are ``match``'s."""
    from logiq_sql.storage.dataset import attach

    db_path = Path(db_path) if db_path is not None else Path(out) / "logiq.duckdb"
    with db.open_for_write(db_path, wait_s, progress) as con:  # its input tables: views over the dataset
        attach(con, dataset)
    kwargs.setdefault("spark_tables", dataset)  # Spark reads the dataset itself
    spark = engine == "spark"
    return match(db_path, engine=engine, wait_s=wait_s, progress=progress, out=None if spark else out,
                 results=out if spark else None, **kwargs)


def select_run_drives(con: duckdb.DuckDBPyConnection, drives: list[str] | None) -> pl.DataFrame:
    known = con.sql("select drive_id from drive_inputs order by drive_id").pl()
    if drives:
        missing = sorted(set(drives) - set(known["drive_id"]))
        if missing:
            raise ScenarioError(f"{arg('drives', missing[0])}: no such drive in the file."
                                f"{did_you_mean(missing[0], known['drive_id'].to_list())}")
        known = known.filter(pl.col("drive_id").is_in(drives))
    return known


def match_batches(con: duckdb.DuckDBPyConnection, ids: tuple[str, ...], batch_rows: int) -> list[list[str]]:
    """``ids`` (sorted) cut into consecutive batches of at most ``batch_rows`` track rows, or one drive each."""
    with registered(con, "_batch_ids", pl.DataFrame({"drive_id": list(ids)}, schema={"drive_id": pl.String})):
        sizes = con.sql("select drive_id, rows_read - rows_rejected as n from drive_inputs "
                        "where drive_id in (select drive_id from _batch_ids) order by drive_id").pl()
    return batches(sizes.iter_rows(), batch_rows)


def drives_to_match(con: duckdb.DuckDBPyConnection, s: Scenario, run_drives: pl.DataFrame, ego: str,
                     range_m: float) -> pl.DataFrame:
    """The drives of the run whose latest run of ``s`` differs in parameters, query texts, ego mode or relation
    range."""
    with registered(con, "_wanted", run_drives):
        return con.sql(
            "select w.drive_id from _wanted as w where not exists (select 1 from drive_scenarios as d "
            "join match_runs as r on r.run_id = d.run_id and r.scenario = d.scenario "
            "where d.drive_id = w.drive_id and d.scenario = $s and d.params_hash = $h and r.queries_hash = $q "
            "and r.ego_mode = $ego and r.relation_range_m = $range) order by w.drive_id",
            params={"s": s.name, "h": s.params_hash(), "q": queries_hash(s), "ego": ego, "range": range_m}).pl()


def read_result(con: duckdb.DuckDBPyConnection, run_drives: pl.DataFrame, names: list[str]) -> MatchResult:
    in_run = "scenario in (select scenario from _names) and drive_id in (select drive_id from run_drives)"
    with registered(con, "run_drives", run_drives), registered(con, "_names", pl.DataFrame({"scenario": names})):
        matches = con.sql(f"select * from matches where {in_run} "
                          "order by scenario, drive_id, ego_id, actor_id, start_frame").pl()
        with registered(con, "_ids", matches.select("match_id")):
            return MatchResult(
                matches=matches,
                match_phases=con.sql("select * from match_phases where match_id in (select match_id from _ids) "
                                     "order by match_id, phase_index").pl(),
                kpis=con.sql("select k.* from kpis k join _ids using (match_id) order by scenario, match_id").pl(),
                coverage=con.sql("select * from coverage where scenario in (select scenario from _names) "
                                 "order by scenario, item, bucket_index nulls last, bucket").pl(),
                drives=con.sql("select * from drives where drive_id in (select drive_id from run_drives) "
                               "order by drive_id").pl(),
            )


def render(scenario: str, *, overrides: dict[str, str] | None = None, ego: str = "auto",
           relation_range: str = DEFAULT_RELATION_RANGE, engine: str = "duckdb",
           scenario_path: ScenarioPath = None, ego_kinds: str | None = None) -> str:
    """The SQL that finds the matches of ``scenario``, as one statement with its parameter values set (DuckDB),
    or as Spark SQL with the values to bind listed above it (``engine="spark"``)."""
    (s,) = resolve_scenarios([scenario], overrides or {}, scenario_path)
    values = run_values(s, parse_ego(ego, ego_kinds), relation_range_m(relation_range))
    if engine != "duckdb":
        return render_for_engine(engine, s, scenario_steps(s), values)
    header = (f"-- scenario {s.name} (version {s.version}), params_hash {s.params_hash()}\n"
              f"-- run against a logiq_sql DuckDB file; run_drives lists the drives to match.\n"
              + ("-- encroachments (shapely, logiq_sql/matching/encroachment.py) is read from the file: match --keep once first.\n"
                 if s.junctions else "")
              + "create or replace temp table run_drives as "
                "select drive_id from drive_inputs where status = 'ingested';\n")
    return header + render_steps(scenario_steps(s), values)
