"""Match scenarios against the drives in a DuckDB file: relations, phases, matches, KPIs, coverage.

Every step is a query file in ``queries/`` run over the whole table set, with bound parameters:

    egos -> actor_lanes -> ego_lanes -> relations          (shared by every scenario of the run)
    phase_1..n -> scenario_match -> scenario_matches       (per scenario)
    kpi queries -> kpis, coverage_samples -> coverage      (per scenario, then over the whole file)

A run is incremental: a (drive, scenario) pair whose latest run had the same params_hash (scenario version and
every bound value), ego mode and relation range is skipped (``force`` reruns it). The rest is matched and
replaces that scenario's outputs on those drives in one transaction per batch of drives (MATCH_BATCH_ROWS), so
memory stays bounded and an interrupted run keeps the batches it finished and the previous results of the rest.
While a batch runs, its queries read only its drives' rows of tracks, track_lanes and traffic_light_states
(``Engine.select_drives``), so a batch costs what its drives hold, whatever the file holds.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql import db, relations_of, units
from logiq_sql.batching import batches
from logiq_sql.db import COVERAGE_BUCKETS, COVERAGE_SAMPLES, MATCH_PHASES, MATCHES
from logiq_sql.encroachment import encroachments
from logiq_sql.engines import Engine, as_engine, check_engine, open_engine, render_for_engine, stored_schema
from logiq_sql.errors import ScenarioError, did_you_mean
from logiq_sql.scenario import Scenario, list_scenarios, load_scenario
from logiq_sql.sql import query_text, recount_coverage, render_steps
from logiq_sql.timing import stage

DEFAULT_RELATION_RANGE = "200m"  # a 5 s headway (the lane-following maximum) at 140 km/h
OBJECT_RELATION_RANGE_M = 50.0  # non-vehicle actors are related to the ego only this close
DEFAULT_LANE_TOLERANCE_M = 1.0  # the spec's default lane_calculation_tolerance_length
# drives are matched in batches of about this many track rows, each stored in its own transaction: memory stays
# bounded whatever the file holds (at 50 M rows one pass over every drive ran out of DuckDB's 4 GB)
MATCH_BATCH_ROWS = 2_000_000
RELATION_STEPS = (
    ("lane_neighbours", "relations/lane_neighbours.sql"),
    ("lane_line", "relations/lane_line.sql"),
    ("actor_lanes", "relations/actor_lanes.sql"),
    ("ego_lanes", "relations/ego_lanes.sql"),
    ("relations", "relations/relations.sql"),
)
# junction geometry, for the scenarios that declare `junctions = true`; encroachments (shapely) come after them
JUNCTION_STEPS = (
    ("actor_paths", "junctions/actor_paths.sql"),
    ("passages", "junctions/passages.sql"),
    ("junction_frames", "junctions/junction_frames.sql"),
    ("crossing_pairs", "junctions/crossing_pairs.sql"),
)
# kept in the file for analysts (and for rendered SQL, which reads encroachments), replaced per drive, with the
# file whose header documents their columns
PERSISTED = {"relations": "queries/relations/relations.sql", "ego_lanes": "queries/relations/ego_lanes.sql",
             "passages": "queries/junctions/passages.sql", "encroachments": "logiq_sql/encroachment.py"}
# stored by every run, the rest of PERSISTED only with ``keep`` (match --keep): evaluate reads which egos the
# matcher used from ego_lanes (a row per ego frame), while relations (about twice the track rows), passages and
# encroachments are recomputed on demand (explain, queries/relations/relations_of.sql)
STORED_ALWAYS = ("ego_lanes",)
ENCROACHMENTS_GRAIN = ("one row per (drive_id, ego_id, actor_id) pair of junction passages whose swept paths share "
                       "an area")


@dataclass
class MatchResult:
    """What one run produced, as Polars frames (the file holds the same, plus earlier runs)."""

    matches: pl.DataFrame
    match_phases: pl.DataFrame
    kpis: pl.DataFrame
    coverage: pl.DataFrame
    drives: pl.DataFrame
    up_to_date: dict[str, int] = field(default_factory=dict)  # scenario -> drives skipped as already matched

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
        return "\n".join(lines)


def parse_ego(ego: str) -> dict[str, object]:
    """``auto | recorded | all | every:N | <actor id>[,<actor id>...]`` -> the egos.sql parameters."""
    if ego in ("auto", "recorded", "all"):
        return {"ego_mode": ego, "ego_every": 1, "ego_actor_ids_csv": ""}
    if ego.startswith("every:"):
        try:
            n = int(ego.split(":", 1)[1])
            if n < 1:
                raise ValueError
        except ValueError:
            raise ScenarioError(f"--ego {ego}: N in every:N must be a whole number >= 1.") from None
        return {"ego_mode": "every", "ego_every": n, "ego_actor_ids_csv": ""}
    return {"ego_mode": "id", "ego_every": 1, "ego_actor_ids_csv": "," + ",".join(i.strip() for i in ego.split(",")) + ","}


def resolve_scenarios(names: list[str] | None, overrides: dict[str, str]) -> list[Scenario]:
    """Load the scenarios and apply each override to every scenario that declares that parameter."""
    scenarios = [load_scenario(n) for n in names] if names else list_scenarios()
    abstract = [s.name for s in scenarios if s.abstract]
    if abstract:
        raise ScenarioError(f"scenario '{abstract[0]}' is a base scenario and cannot be matched on its own.")
    known = {p for s in scenarios for p in s.params}
    for name, text in overrides.items():
        if name not in known:
            raise ScenarioError(
                f"--set {name}={text}: no scenario of this run has a parameter '{name}'."
                f"{did_you_mean(name, sorted(known))}\n\nHint: `logiq-sql scenarios` lists every parameter."
            )
    return [s.with_overrides({k: v for k, v in overrides.items() if k in s.params}) for s in scenarios]


def _lane_tolerance(s: Scenario) -> float:
    p = s.params.get("lane_calculation_tolerance_length")
    return float(p.value) if p is not None and p.value is not None else DEFAULT_LANE_TOLERANCE_M


def _phase_limits(s: Scenario) -> dict[str, object]:
    """``phase_<i>_min_duration_s`` / ``phase_<i>_max_duration_s`` for the match queries: the values of the
    parameters each phase names as its limits (no minimum: 0; no maximum: NULL)."""
    out: dict[str, object] = {}
    for i, phase in enumerate(s.phases, 1):
        lo = s.params[phase.min_duration].value if phase.min_duration else None
        hi = s.params[phase.max_duration].value if phase.max_duration else None
        out[f"phase_{i}_min_duration_s"] = 0.0 if lo is None else lo
        out[f"phase_{i}_max_duration_s"] = hi
    return out


def run_values(s: Scenario, ego: dict[str, object], relation_range_m: float) -> dict[str, object]:
    """Every value a step of scenario ``s`` may bind."""
    return {
        **s.bindings(), **_phase_limits(s), **ego, "relation_range_m": relation_range_m,
        "object_relation_range_m": min(relation_range_m, OBJECT_RELATION_RANGE_M),
        "lane_calculation_tolerance_length_m": _lane_tolerance(s),
        "scenario": s.name, "scenario_version": s.version, "params_hash": s.params_hash(),
        "phase_count": len(s.phases),
    }


def phase_steps(s: Scenario) -> list[tuple[str, str]]:
    """The steps from the relations to the scenario's matches (table, query)."""
    if s.frames_query:
        steps = [("phase_frames", s.frames_query), ("phase_islands", "match/phase_islands.sql"),
                 ("chain", "match/chain.sql")]
    else:
        steps = [(f"phase_{i}", p.query or "") for i, p in enumerate(s.phases, 1)]
    return [*steps, ("scenario_match", s.match_query or "")]


def scenario_steps(s: Scenario) -> list[tuple[str, str]]:
    """Every SQL step of a scenario, in order. Junction scenarios also read ``encroachments``, which shapely
    computes between crossing_pairs and the phases (logiq_sql/encroachment.py); rendered SQL reads the stored
    table."""
    return [("egos", "relations/egos.sql"), *RELATION_STEPS, *(JUNCTION_STEPS if s.junctions else ()),
            *phase_steps(s)]


def render(scenario: str, overrides: dict[str, str] | None = None, ego: str = "auto",
           relation_range: str = DEFAULT_RELATION_RANGE, engine: str = "duckdb") -> str:
    """The SQL that finds the matches of ``scenario``, as one statement with its parameter values set (DuckDB),
    or as Spark SQL with the values to bind listed above it (``engine="spark"``)."""
    (s,) = resolve_scenarios([scenario], overrides or {})
    values = run_values(s, parse_ego(ego), units.parse(relation_range, "length", "--relation-range"))
    if engine != "duckdb":
        return render_for_engine(engine, s, scenario_steps(s), values)
    header = (f"-- scenario {s.name} (version {s.version}), params_hash {s.params_hash()}\n"
              f"-- run against a logiq_sql DuckDB file; run_drives lists the drives to match.\n"
              + ("-- encroachments (shapely, logiq_sql/encroachment.py) is read from the file: match --keep once first.\n"
                 if s.junctions else "")
              + "create or replace temp table run_drives as "
                "select drive_id from drive_inputs where status = 'ingested';\n")
    return header + render_steps(scenario_steps(s), values)


def _coverage_buckets(s: Scenario) -> pl.DataFrame:
    rows = []
    for item in s.coverage:
        if item.values:
            rows += [dict(scenario=s.name, item=item.name, bucket_index=i, bucket=v, lo=None, hi=None, value_text=v)
                     for i, v in enumerate(item.values)]
            continue
        n = round((item.hi - item.lo) / item.every)
        for i in range(n):
            lo = item.lo + i * item.every
            hi = min(item.lo + (i + 1) * item.every, item.hi)
            rows.append(dict(scenario=s.name, item=item.name, bucket_index=i, bucket=f"[{lo:g}, {hi:g})",
                             lo=lo, hi=hi, value_text=None))
    return pl.DataFrame(rows, schema=COVERAGE_BUCKETS.polars_schema)


def _coverage_samples(s: Scenario, metrics: pl.DataFrame) -> pl.DataFrame:
    frames = []
    for item in s.coverage:
        col = pl.col(item.column)
        frames.append(metrics.select(
            pl.lit(s.name).alias("scenario"), pl.col("match_id"), pl.lit(item.name).alias("item"),
            pl.lit(item.unit).alias("unit"),
            (pl.lit(None, pl.Float64) if item.values else col.cast(pl.Float64)).alias("value_num"),
            (col.cast(pl.String) if item.values else pl.lit(None, pl.String)).alias("value_text"),
        ))
    return pl.concat(frames) if frames else pl.DataFrame(schema=COVERAGE_SAMPLES.polars_schema)


TEXT_UNITS = ("string", "evaluation_object_kind")


def _metric_columns(s: Scenario) -> dict[str, tuple[str, str, str]]:
    """Columns of ``kpis`` for a scenario: its KPIs, then its coverage samples -> (unit, SQL type, description)."""
    out = {k.column: (k.unit, "varchar" if k.unit in TEXT_UNITS else "double",
                      f"{k.name} ({k.unit}): {k.description}") for k in s.kpis}
    for c in s.coverage:
        out.setdefault(c.column, (c.unit, "varchar" if c.values else "double",
                                  f"coverage item {c.name} ({c.unit}), sampled at the {c.sample}: {c.description}"))
    return out


def _ensure_kpi_columns(con: duckdb.DuckDBPyConnection, scenarios: list[Scenario]) -> None:
    con.execute("create table if not exists kpis (match_id varchar not null, scenario varchar not null)")
    con.execute("comment on table kpis is 'One row per match: every KPI and sampled coverage value of its scenario, in the spec''s "
                "units (column suffix); NULL where the scenario does not record that KPI or the value is undefined.'")
    con.execute("comment on column kpis.match_id is 'Match (matches.match_id).'")
    con.execute("comment on column kpis.scenario is 'Scenario.'")
    have = {r[0] for r in con.execute(
        "select column_name from duckdb_columns() where table_name = 'kpis'").fetchall()}
    for s in scenarios:
        for column, (_unit, sql_type, doc) in _metric_columns(s).items():
            if column not in have:
                con.execute(f"alter table kpis add column {column} {sql_type}")
                con.execute(f"comment on column kpis.{column} is " + db._quote(doc))
                have.add(column)


def prepare_relations(con: duckdb.DuckDBPyConnection | Engine, group: list[Scenario],
                      values: dict[str, object]) -> None:
    """The steps every scenario of ``group`` (one lane tolerance) shares: egos, relations and, when one of them
    needs it, the junction geometry and the encroachment areas."""
    engine = as_engine(con)
    with stage("relations"):
        engine.materialise("egos", "relations/egos.sql", values)
        for table, rel in RELATION_STEPS:
            engine.materialise(table, rel, values)
    if any(s.junctions for s in group):
        with stage("junctions"):
            for table, rel in JUNCTION_STEPS:
                engine.materialise(table, rel, values)
            engine.register("encroachments", encroachments(engine))


def match(db_path: str | Path, scenarios: list[str] | None = None, ego: str = "auto",
          overrides: dict[str, str] | None = None, drives: list[str] | None = None,
          relation_range: str = DEFAULT_RELATION_RANGE, out: str | Path | None = None,
          progress: Callable[[str], None] | None = None, force: bool = False, engine: str = "duckdb",
          spark_master: str | None = None, spark_tables: str | Path | None = None,
          batch_rows: int = MATCH_BATCH_ROWS, keep: bool = False) -> MatchResult:
    """Match scenarios against the drives in ``db_path`` and store matches, KPIs and coverage there.

    Args:
        db_path: a DuckDB file written by ``ingest``.
        scenarios: scenario names (default: every concrete scenario in ``scenarios/``).
        ego: ``auto`` (recorded ego, else every vehicle), ``recorded``, ``all``, ``every:N`` or actor ids
            (comma-separated).
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
            batch is stored in its own transaction, so a killed run keeps the batches it finished.
        keep: also store the intermediate tables relations, passages and encroachments for analysts (ego_lanes
            is always stored); without it, any such rows an earlier run kept for these drives are removed.
    """
    say = progress or (lambda _msg: None)
    chosen = resolve_scenarios(scenarios, overrides or {})
    ego_values = parse_ego(ego)
    range_m = units.parse(relation_range, "length", "--relation-range")
    con = db.connect(db_path)
    runner = None
    try:
        run_drives = _run_drives(con, drives)
        check_engine(engine, [rel for s in chosen for _, rel in scenario_steps(s)]
                     + ["match/identify.sql", *(rel for s in chosen for rel in s.kpi_queries)])
        runner = open_engine(engine, con, spark_master, None if spark_tables is None else str(spark_tables))
        relations_of.install(con)  # the relation of any ego on demand, since relations is kept only with keep
        _ensure_kpi_columns(con, chosen)
        run_id = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S%fZ")
        # scenarios that share a lane tolerance and the drives still to match share their relations
        groups: dict[tuple[float, tuple[str, ...]], list[Scenario]] = {}
        up_to_date: dict[str, int] = {}
        for s in chosen:
            todo = run_drives if force else _drives_to_match(con, s, run_drives, ego, range_m)
            up_to_date[s.name] = run_drives.height - todo.height
            if todo.height:
                groups.setdefault((_lane_tolerance(s), tuple(todo["drive_id"])), []).append(s)
        work = [(tolerance, batch, group) for (tolerance, ids), group in sorted(groups.items())
                for batch in _match_batches(con, ids, batch_rows)]
        for step, (tolerance, batch, group) in enumerate(work, 1):
            todo = pl.DataFrame({"drive_id": batch}, schema={"drive_id": pl.String})
            con.register("run_drives", todo)
            if runner.name != "duckdb":  # the DuckDB engine reads the registered frame directly
                runner.register("run_drives", todo)
            say(f"[{step}/{len(work)}] {len(batch)} drive(s): {', '.join(s.name for s in group)}")
            for table in PERSISTED:  # a group keeps only the tables it computes, for its own drives
                con.execute(f"drop table if exists temp.main.{table}")
            runner.select_drives()
            prepare_relations(runner, group, run_values(group[0], ego_values, range_m))
            say(f"  relations: {runner.frame('select count(*) as n from relations')['n'][0]:,} ego-actor rows "
                f"(lane tolerance {tolerance:g} m)")
            results = []
            for s in group:
                results.append(_run_scenario(runner, s, run_values(s, ego_values, range_m)))
                say(f"  {s.name}: {results[-1][0].height} matches")
            runner.persist(tuple(PERSISTED))
            runner.release_drives()
            _store(con, run_id, ego, range_m, todo, results, keep)
        con.register("run_drives", run_drives)
        result = _result(con, run_drives, [s.name for s in chosen])
        result.up_to_date = up_to_date
        if out is not None:
            export(con, out)
        return result
    finally:
        if runner is not None:
            runner.close()
        con.close()


def _run_drives(con: duckdb.DuckDBPyConnection, drives: list[str] | None) -> pl.DataFrame:
    known = con.sql("select drive_id from drive_inputs order by drive_id").pl()
    if drives:
        missing = sorted(set(drives) - set(known["drive_id"]))
        if missing:
            raise ScenarioError(f"--drive {missing[0]}: no such drive in the file."
                                f"{did_you_mean(missing[0], known['drive_id'].to_list())}")
        known = known.filter(pl.col("drive_id").is_in(drives))
    return known


def _match_batches(con: duckdb.DuckDBPyConnection, ids: tuple[str, ...], batch_rows: int) -> list[list[str]]:
    """``ids`` (sorted) cut into consecutive batches of at most ``batch_rows`` track rows, or one drive each."""
    con.register("_batch_ids", pl.DataFrame({"drive_id": list(ids)}, schema={"drive_id": pl.String}))
    sizes = con.sql("select drive_id, rows_read - rows_rejected as n from drive_inputs "
                    "where drive_id in (select drive_id from _batch_ids) order by drive_id").pl()
    con.unregister("_batch_ids")
    return batches(sizes.iter_rows(), batch_rows)


def _drives_to_match(con: duckdb.DuckDBPyConnection, s: Scenario, run_drives: pl.DataFrame, ego: str,
                     range_m: float) -> pl.DataFrame:
    """The drives of the run whose latest run of ``s`` differs in parameters, ego mode or relation range."""
    con.register("_wanted", run_drives)
    todo = con.sql(
        "select w.drive_id from _wanted as w where not exists (select 1 from drive_scenarios as d "
        "join match_runs as r on r.run_id = d.run_id and r.scenario = d.scenario "
        "where d.drive_id = w.drive_id and d.scenario = $s and d.params_hash = $h and r.ego_mode = $ego "
        "and r.relation_range_m = $range) order by w.drive_id",
        params={"s": s.name, "h": s.params_hash(), "ego": ego, "range": range_m}).pl()
    con.unregister("_wanted")
    return todo


def _run_scenario(engine: Engine, s: Scenario, values: dict[str, object]):
    with stage(f"scenario {s.name}"):
        for table, rel in phase_steps(s):
            engine.materialise(table, rel, values)
        engine.materialise("scenario_matches", "match/identify.sql", values)
        matches = engine.frame("scenario_matches")
    metrics = matches.select("match_id")
    with stage("kpis"):
        for rel in s.kpi_queries:
            engine.materialise("_kpi", rel, values)
            metrics = metrics.join(engine.frame("_kpi"), on="match_id", how="left")
    kpis = metrics.select(pl.col("match_id"), pl.lit(s.name).alias("scenario"),
                          *[pl.col(c) for c in _metric_columns(s)])
    phases = pl.concat([
        matches.select("match_id", "scenario", pl.lit(i, pl.Int64).alias("phase_index"),
                       pl.lit(phase.name).alias("phase"),
                       *[pl.col(f"p{i}_{c}").alias(c) for c in ("start_frame", "end_frame", "start_s", "end_s")])
        for i, phase in enumerate(s.phases, 1)
    ])
    egos = engine.frame("select drive_id, count(*) as egos from egos group by drive_id")
    return matches, phases, kpis, _coverage_samples(s, metrics), _coverage_buckets(s), s, egos


def _store(con: duckdb.DuckDBPyConnection, run_id: str, ego: str, range_m: float, run_drives: pl.DataFrame,
           results, keep: bool = False) -> None:
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    stored = stored_schema(con)  # the run's temp tables shadow the stored ones of the same name
    made = {r[0] for r in con.execute("select table_name from duckdb_tables() where temporary").fetchall()}
    for table in (t for t in PERSISTED if t in made and (keep or t in STORED_ALWAYS)):
        # created empty in a transaction of its own: a DuckDB 2.0 table created and filled in one transaction
        # keeps the empty table's statistics, so filters on it (`where drive_id = ...`, the delete below in a
        # later batch) skipped every row (kept relations were stored twice)
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
            _describe_persisted(con, stored, table)
        for matches, phases, kpis, samples, buckets, s, egos in results:
            # rows that hang off the matches first, then the matches themselves
            for table in ("match_phases", "kpis", "coverage_samples"):
                con.execute(f"delete from {table} where scenario = $s and match_id in (select match_id from matches "
                            "where scenario = $s and drive_id in (select drive_id from run_drives))", {"s": s.name})
            con.execute("delete from matches where scenario = $s and drive_id in (select drive_id from run_drives)",
                        {"s": s.name})
            con.execute("delete from coverage_buckets where scenario = $s", {"s": s.name})
            con.execute("delete from drive_scenarios where scenario = $s and drive_id in "
                        "(select drive_id from run_drives)", {"s": s.name})
            db.insert(con, "matches", matches.with_columns(run_id=pl.lit(run_id)).select(MATCHES.column_names))
            db.insert(con, "match_phases", phases.select(MATCH_PHASES.column_names))
            db.insert(con, "kpis", kpis)
            db.insert(con, "coverage_samples", samples)
            db.insert(con, "coverage_buckets", buckets)
            db.insert(con, "drive_scenarios",
                      _drive_status(con, run_drives, matches, egos, s).with_columns(run_id=pl.lit(run_id)))
            # one row per run and scenario: a later batch of the same run adds its drives and matches
            (before,) = con.execute(
                "select min(started_at), coalesce(sum(drives), 0), coalesce(sum(matches), 0) from match_runs "
                "where run_id = $r and scenario = $s", {"r": run_id, "s": s.name}).fetchall()
            con.execute("delete from match_runs where run_id = $r and scenario = $s", {"r": run_id, "s": s.name})
            db.insert(con, "match_runs", pl.DataFrame([{
                "run_id": run_id, "started_at": before[0] or started, "scenario": s.name,
                "scenario_version": s.version, "params_hash": s.params_hash(),
                "params_json": json.dumps(s.bindings(), sort_keys=True),
                "overrides": json.dumps(s.overrides, sort_keys=True), "ego_mode": ego,
                "drives": before[1] + run_drives.height, "matches": before[2] + matches.height,
                "relation_range_m": range_m,
            }], schema=db.MATCH_RUNS.polars_schema))
        with stage("coverage"):
            recount_coverage(con)
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise


def _describe_persisted(con: duckdb.DuckDBPyConnection, stored: str, table: str) -> None:
    """Table and column comments for a kept table, from the header of the file that defines it."""
    source = PERSISTED[table]
    if source.endswith(".sql"):
        grain, docs = db.header_docs(query_text(source.removeprefix("queries/")))
    else:
        grain, docs = ENCROACHMENTS_GRAIN, {}
    db.comment_derived(con, f"{stored}.{table}", table,
                       f"Kept from the last match run of each drive: {grain} ({source}, docs/semantics.md).",
                       docs, f"See the header of {source} and docs/semantics.md.")


def _drive_status(con, run_drives: pl.DataFrame, matches: pl.DataFrame, egos: pl.DataFrame, s: Scenario):
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


def _result(con: duckdb.DuckDBPyConnection, run_drives: pl.DataFrame, names: list[str]) -> MatchResult:
    con.register("_names", pl.DataFrame({"scenario": names}))
    in_run = ("scenario in (select scenario from _names) and drive_id in (select drive_id from run_drives)")
    matches = con.sql(f"select * from matches where {in_run} order by scenario, drive_id, ego_id, actor_id, start_frame").pl()
    con.register("_ids", matches.select("match_id"))
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


EXPORTED = ("drives", "matches", "match_phases", "kpis", "coverage", "coverage_samples", "match_runs",
            "drive_scenarios")


def export(con: duckdb.DuckDBPyConnection, out: str | Path) -> None:
    """Write the output tables as Parquet files in ``out`` (sorted, so reruns give the same files)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for table in EXPORTED:
        frame = con.sql(f"select * from {table}").pl()
        keys = [c for c in ("scenario", "drive_id", "match_id", "item", "bucket_index", "bucket", "run_id",
                            "phase_index") if c in frame.columns]
        frame.sort(keys, nulls_last=True).write_parquet(out / f"{table}.parquet")
