"""The same queries/ SQL on Spark (local mode) gives the same matches, phases, KPIs and coverage as DuckDB.

Marked ``spark``: part of ``make test`` (CI installs the [spark] extra; Java 17 is on the machines). Without
PySpark the tests are skipped with the reason, except under CI=true, where they fail. One Spark session for the
module (local[2], no UI, 4 shuffle partitions; the client JIT only: tests/conftest.py).
"""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

import duckdb
import polars as pl
import pytest
import sqlglot

from logiq_sql import ingest, match
from logiq_sql.cli.lint import spark_problems

pytestmark = pytest.mark.spark
DATA = Path(__file__).parents[1] / "data"
LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"
REL_TOL = 1e-9  # Spark's sums and cos/sin may differ from DuckDB's in the last bits (docs/engines.md)


@pytest.fixture(scope="module")
def spark(client_jit):
    try:
        import pyspark  # noqa: F401
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("CI=true but PySpark is not installed: pip install '.[spark]' (make venv does).")
        pytest.skip("PySpark is not installed: pip install 'logiq-sql[spark]' (needs Java 17).")
    from logiq_sql.engines.spark_engine import spark_session

    started = time.perf_counter()
    session = spark_session("local[2]")
    session.sparkContext.setLogLevel("OFF")  # the lint test makes Spark log an intended analysis error
    print(f"\nSpark session start: {time.perf_counter() - started:.1f} s")
    yield session
    session.stop()


def twin_files(tmp: Path, name: str, ingests) -> tuple[Path, Path]:
    """One ingest, copied: the DuckDB engine matches one file, the Spark engine the other."""
    duck = tmp / f"{name}_duckdb.duckdb"
    for fmt, paths in ingests:
        ingest(fmt, paths, duck)
    spark = tmp / f"{name}_spark.duckdb"
    shutil.copy(duck, spark)
    return duck, spark


def match_both(duck: Path, spark_db: Path, **kwargs) -> dict[str, float]:
    seconds = {}
    for engine, db in (("duckdb", duck), ("spark", spark_db)):
        started = time.perf_counter()
        match(db, engine=engine, keep=True, **kwargs)  # keep: the kept relation tables are compared too
        seconds[engine] = time.perf_counter() - started
    print(f"\nmatch {kwargs.get('scenarios')}: DuckDB {seconds['duckdb']:.1f} s, Spark {seconds['spark']:.1f} s")
    return seconds


OUTPUTS = {  # table -> sort key (every output table the matcher writes, except the run log)
    "matches": ["match_id"],
    "match_phases": ["match_id", "phase_index"],
    "kpis": ["match_id"],
    "coverage_samples": ["match_id", "item"],
    "coverage": ["scenario", "item", "bucket"],
    "drive_scenarios": ["drive_id", "scenario"],
    "relations": ["drive_id", "ego_id", "actor_id", "frame"],
    "ego_lanes": ["drive_id", "ego_id", "frame"],
}


def read_output(db: Path, table: str, keys: list[str] | None = None) -> pl.DataFrame | None:
    with duckdb.connect(str(db), read_only=True) as con:
        # tables, or views over the Parquet a Spark run wrote (logiq_sql/matching/spark_out.py)
        have = {r[0] for r in con.execute("select table_name from information_schema.tables").fetchall()}
        if table not in have:
            return None
        # run_id is the time of the run: the two runs differ in it by construction
        return con.sql(f"select * exclude (run_id) from {table}" if "run_id" in con.table(table).columns
                       else f"select * from {table}").pl().sort(keys or OUTPUTS[table])


def assert_same_outputs(duck: Path, spark_db: Path, tables=OUTPUTS) -> None:
    inexact = total = 0
    worst = worst_abs = 0.0
    for table, keys in tables.items():
        a, b = read_output(duck, table, keys), read_output(spark_db, table, keys)
        if a is None:
            assert b is None, table
            continue
        assert a.schema == b.schema, table
        assert a.height == b.height, (table, a.height, b.height)
        for col, dtype in a.schema.items():
            x, y = a[col], b[col]
            if dtype != pl.Float64:
                assert x.to_list() == y.to_list(), (table, col)
                continue
            assert (x.is_null() == y.is_null()).all(), (table, col)
            scale = pl.DataFrame({"x": x.abs(), "y": y.abs()}).max_horizontal()
            close = ((x - y).abs() <= REL_TOL * scale + 1e-12).fill_null(True)
            assert close.all(), (table, col, pl.DataFrame({"duckdb": x, "spark": y}).filter(~close).head(3))
            differs = (x != y).fill_null(False)
            total += x.is_not_null().sum()
            inexact += differs.sum()
            worst_abs = max(worst_abs, (x - y).abs().filter(differs).max() or 0.0)
            # relative size, for the values not already within the absolute tolerance (near 0 it means nothing)
            worst = max(worst, ((x - y).abs() / scale).filter(differs & ((x - y).abs() > 1e-12)).max() or 0.0)
    print(f"\n{inexact} of {total} float values differ from DuckDB's: at most {worst_abs:.2g} absolute, and "
          f"{worst:.2g} relative beyond 1e-12 absolute (tolerance {REL_TOL:g} relative)")


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    cr = DATA / "commonroad_ngsim/scenarios_2018b"
    nu = DATA / "nuscenes_mini_scenarionet"
    return twin_files(tmp_path_factory.mktemp("real"), "real", [
        ("commonroad", [cr / "USA_US101-22_1_T-1.xml.gz"]),
        ("scenarionet", [nu / "sd_nuscenes_v1.0-mini_scene-0103.pkl"])])


def test_spark_matches_duckdb_on_real_drives(spark, real):
    """NGSIM US-101 (followers, cut-outs; every 4th car the SUT in turn, for time) and nuScenes scene-0103 (the
    recorded ego and the cyclist, within 6 m). The cyclist is matched on scene-0103 first, so the run of the three
    scenarios is incremental and has two groups (the cyclist on US-101 only; the others on both drives): each
    group must keep only the tables it computed, on both engines."""
    duck, spark_db = real
    six_m = {"max_distance_from_cyclist": "6m"}
    match_both(duck, spark_db, scenarios=["cyclist_close_to_moving_sut"], overrides=six_m, ego="every:4",
          drives=["scene-0103"])
    # one drive per batch: each batch's queries read only its drive's rows (Engine.select_drives)
    match_both(duck, spark_db, scenarios=["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut"],
          overrides=six_m, ego="every:4", batch_rows=1)
    counts = read_output(duck, "matches").group_by("scenario").len().sort("scenario").rows()
    assert [s for s, n in counts if n > 0] == ["cyclist_close_to_moving_sut", "follower_vehicle", "sut_cut_out"]
    assert_same_outputs(duck, spark_db)


def test_spark_matches_duckdb_on_a_simulated_junction(spark, tmp_path_factory):
    """The bundled SUMO junction (signal states known), every 40th vehicle as the SUT: left turns with PET and
    the encroachment areas (shapely between the Spark steps)."""
    duck, spark_db = twin_files(tmp_path_factory.mktemp("sumo"), "sumo", [("sumo", [DATA / "sumo/junction_s1"])])
    match_both(duck, spark_db, scenarios=[LEFT_TURN], ego="every:40")
    assert read_output(duck, "matches").height > 0
    assert_same_outputs(duck, spark_db, {**OUTPUTS, "passages": ["drive_id", "actor_id", "passage"],
                                  "encroachments": ["drive_id", "ego_id", "ego_passage", "actor_id", "actor_passage"]})


def test_spark_writes_the_results_of_a_dataset_itself(spark, tmp_path, monkeypatch, capsys):
    """``match --engine spark --dataset DIR --out OUT``: Spark writes every output table as Parquet partitioned by
    scenario and drive (logiq_sql/matching/spark_out.py), nothing of the results comes back to the driver, and the views
    in OUT/logiq.duckdb give DuckDB's results. A rerun replaces partitions (no duplicates); a drive added to the
    dataset later is matched alone, incrementally."""
    from logiq_sql.cli import EXIT_OK, main
    from logiq_sql.engines.spark_engine import SparkEngine

    cr, nu = DATA / "commonroad_ngsim/scenarios_2018b", DATA / "nuscenes_mini_scenarionet"
    first = [("commonroad", [cr / "USA_US101-22_1_T-1.xml.gz"])]
    later = ("scenarionet", [nu / "sd_nuscenes_v1.0-mini_scene-0103.pkl"])
    # two scenarios: what is tested here is the writing, not the SQL (the tests above compare every scenario)
    scenarios = ["follower_vehicle", "cyclist_close_to_moving_sut"]
    args = [*(a for s in scenarios for a in ("--scenario", s)), "--ego", "every:4", "--set",
            "max_distance_from_cyclist=6m", "--keep", "--quiet"]
    dataset, out = tmp_path / "dataset", tmp_path / "out"
    asked = []  # every query the driver collected: only counts for the progress lines may come back
    collect = SparkEngine.frame
    monkeypatch.setattr(SparkEngine, "frame", lambda self, sql: asked.append(sql) or collect(self, sql))
    monkeypatch.setattr("logiq_sql.engines.base.copy_into_duckdb", lambda *a: pytest.fail("a table came to the driver"))

    def both(ingests, *extra) -> Path:
        duck = tmp_path / f"duck_{len(ingests)}.duckdb"
        for fmt, paths in ingests:
            ingest(fmt, paths, duck)
            assert main(["ingest", fmt, *map(str, paths), "--dataset", str(dataset), "--quiet"]) == EXIT_OK
        match(duck, scenarios=scenarios, ego="every:4", overrides={"max_distance_from_cyclist": "6m"}, keep=True)
        assert main(["match", "--dataset", str(dataset), "--out", str(out), "--engine", "spark", *args,
                     *extra]) == EXIT_OK
        return duck

    duck = both(first)
    kept = {**OUTPUTS, "passages": ["drive_id", "actor_id", "passage"]}
    assert_same_outputs(duck, out / "logiq.duckdb", kept)
    assert asked and all(re.fullmatch(r"select count\(\*\) as n from relations", q) for q in asked), asked
    # Spark's own part files, one folder per scenario and drive
    parts = sorted(p.relative_to(out / "matches").parts[:2] for p in (out / "matches").rglob("part-*.parquet"))
    assert ("scenario=follower_vehicle", "drive_id=USA_US101-22_1_T-1@2018b") in parts, parts
    assert (out / "matches" / "_SUCCESS").is_file()
    with duckdb.connect(str(out / "logiq.duckdb"), read_only=True) as con:
        kinds = dict(con.execute("select table_name, table_type from information_schema.tables "
                                 "where table_name in ('matches', 'kpis', 'tracks')").fetchall())
        assert kinds == {"matches": "VIEW", "kpis": "VIEW", "tracks": "VIEW"}, kinds
        before = con.execute("select count(*) from matches").fetchone()[0]

    # --force reruns: every partition replaced, none doubled
    assert main(["match", "--dataset", str(dataset), "--out", str(out), "--engine", "spark", *args,
                 "--force"]) == EXIT_OK
    assert_same_outputs(duck, out / "logiq.duckdb", kept)
    with duckdb.connect(str(out / "logiq.duckdb"), read_only=True) as con:
        assert con.execute("select count(*) from matches").fetchone()[0] == before
        assert con.execute("select count(distinct run_id) from match_runs").fetchone()[0] == 2

    # a drive added later: only it is matched, and the whole equals DuckDB's results over both drives
    capsys.readouterr()
    duck = both([*first, later])
    assert "already up to date" in capsys.readouterr().out
    assert_same_outputs(duck, out / "logiq.duckdb", kept)


@pytest.fixture(scope="module")
def analysed(spark):
    """Every query file through Spark's analyser; leaves empty views of every table and step behind."""
    return spark_problems(spark)


def test_every_query_analyses_on_spark(analysed):
    """Every query file, transpiled and with its parameters bound, passes Spark's analyser over empty canonical
    tables (in scenario order, so each step reads the views of the steps before it)."""
    assert analysed == []


def test_lint_runs_queries_on_spark_and_reports_what_fails(spark, tmp_path):
    """A function DuckDB has and Spark does not: sqlglot passes it through; Spark's analyser names it."""
    root = tmp_path / "queries"
    (root / "phases").mkdir(parents=True)
    (root / "phases/odd.sql").write_text("select regexp_full_match(kind, 'c.*') as m from tracks")
    from logiq_sql.cli.lint import spark_problems_in

    text = sqlglot.transpile((root / "phases/odd.sql").read_text(), read="duckdb", write="spark")[0]
    problems = spark_problems_in(spark, "phases/odd.sql", text, {})
    assert len(problems) == 1 and "regexp_full_match" in problems[0].lower(), problems


def test_rendered_spark_sql_binds_its_parameters_and_parses(spark):
    """render --engine spark: the values are comments and args, never SQL text; Spark parses the statement."""
    from logiq_sql.engines.spark_engine import render_spark_steps
    from logiq_sql.matching.match import parse_ego, render, resolve_scenarios, run_values, scenario_steps

    for s in resolve_scenarios(None, {"max_distance_from_cyclist": "6m"}):
        values = run_values(s, parse_ego("auto"), 200.0)
        text, args = render_spark_steps(scenario_steps(s), values)
        code = re.sub(r"/\*.*?\*/", "", text, flags=re.DOTALL)  # the query files' comments name their $parameters
        assert "$" not in code and all(f":{name}" in code for name in args)
        # Spark's analyser cannot take a whole scenario as one statement since the phase contract (Max iterations,
        # or an OutOfMemoryError that would leave the shared JVM unusable, so it is not provoked here): the statement
        # must parse, and every step of it is analysed on its own by test_every_query_analyses_on_spark, as
        # match --engine spark runs it.
        assert spark._jsparkSession.sessionState().sqlParser().parsePlan(text) is not None
        assert "run it step by step" in render(s.name, overrides=dict(s.overrides), engine="spark")
        printed = render(s.name, overrides={k: v for k, v in s.overrides.items()}, engine="spark")
        assert printed.endswith(text + "\n")
        assert all(f"-- :{name} = " in printed for name in args)
    cyclist = render("cyclist_close_to_moving_sut", overrides={"max_distance_from_cyclist": "6m"}, engine="spark")
    assert "-- :max_distance_from_cyclist_m = 6.0\n" in cyclist


def test_a_step_s_size_estimate_stays_bounded_however_many_steps_join_before_it(spark):
    """Spark's size-only estimator multiplies a join's two sides, and a checkpoint carries its plan's estimate: a
    step that joins the step before it with itself doubled the estimate's digits each time, until the driver's heap
    ran out (a cluster run in CI). spark_engine.checkpoint keeps every estimate within a long."""
    from logiq_sql.engines.spark_engine import LONG_MAX, checkpoint

    step = checkpoint(spark.range(50).selectExpr("id as k", "id as v"))
    for _ in range(16):  # carried, the estimate would have some 19 * 2**16 digits
        step.createOrReplaceTempView("_previous_step")
        step = checkpoint(spark.sql("select a.k, a.v + b.v as v from _previous_step a join _previous_step b using (k)"))
        assert step._jdf.queryExecution().optimizedPlan().stats().sizeInBytes() <= LONG_MAX
    assert sorted(step.collect()) == [(k, k * 2**16) for k in range(50)]
