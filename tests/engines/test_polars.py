"""Polars SQL against DuckDB, query file by query file, so the verdict table (engines.polars_engine.POLARS_UNSUPPORTED) cannot
rot: a portable query it does not list must give DuckDB's rows over the same inputs; a query it lists must fail
with the listed error. What the engine runs instead (a Polars override in queries/overrides/polars/, or the match
ids' md5 computed afterwards) must give DuckDB's rows too. --engine polars runs the scenarios whose every file it
can run, with DuckDB's results, and stops before anything runs, naming the query file and the reason, otherwise.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import polars as pl
import pytest

from logiq_sql import ingest, match
from logiq_sql.core.paths import data_dir
from logiq_sql.core.sql import PER_PHASE, query_text
from logiq_sql.engines.base import EngineError
from logiq_sql.engines.duckdb_engine import DuckEngine
from logiq_sql.engines.polars_engine import POLARS_UNSUPPORTED, PolarsEngine, override, polars_blocker
from logiq_sql.matching.encroachment import encroachments
from logiq_sql.matching.match import select_run_drives
from logiq_sql.spec.plan import (
    parse_ego,
    resolve_scenarios,
    result_steps,
    run_values,
    scenario_steps,
)
from logiq_sql.storage import db

DATA = Path(__file__).parents[1] / "data"
LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"


def _same_rows(duck: pl.DataFrame, got: pl.DataFrame, where: str) -> None:
    assert got.columns == duck.columns, where
    assert got.height == duck.height, (where, duck.height, got.height)
    a, b = duck.sort(duck.columns, nulls_last=True), got.sort(got.columns, nulls_last=True)
    for col in a.columns:
        x, y = a[col], b[col]
        if x.dtype.is_float():
            assert (x.is_null() == y.is_null()).all(), (where, col)
            diff = (x - y.cast(pl.Float64)).abs() <= 1e-9 * x.abs() + 1e-12
            assert diff.fill_null(True).all(), (where, col)
        else:
            assert x.to_list() == y.cast(x.dtype).to_list(), (where, col)


def _verdict(polars: PolarsEngine, duck: pl.DataFrame, relative: str, values: dict[str, object],
             ran_otherwise: set[str]) -> None:
    """The portable text against the verdict table; then, where the engine runs the file another way (an
    override, md5 afterwards), that way against DuckDB's rows; a file the engine cannot run must fail."""
    if relative in POLARS_UNSUPPORTED:
        with pytest.raises(Exception, match=re.escape(POLARS_UNSUPPORTED[relative])):
            polars.run(relative, values, portable=True)
    else:
        _same_rows(duck, polars.run(relative, values, portable=True), relative)
    if polars_blocker(relative) is not None:
        with pytest.raises(Exception, match=re.escape(POLARS_UNSUPPORTED[relative])):
            polars.run(relative, values)
    elif relative in POLARS_UNSUPPORTED or override("polars", relative):
        _same_rows(duck, polars.run(relative, values), f"{relative} as the Polars engine runs it")
        ran_otherwise.add(relative)


def _walk(path: Path, scenarios: list[str], ego: str, overrides: dict[str, str], checked: set[str],
          ran_otherwise: set[str]) -> None:
    """Every step of the scenarios on DuckDB; each query file also on Polars over DuckDB's inputs to it."""
    con = db.connect(path)
    try:
        run_drives = select_run_drives(con, None)
        con.register("run_drives", run_drives)
        duck, polars = DuckEngine(con), PolarsEngine(con)
        polars.register("run_drives", run_drives)
        for s in resolve_scenarios(scenarios, overrides):
            values = run_values(s, parse_ego(ego), 200.0)
            for table, rel in [*scenario_steps(s), *result_steps(s)]:
                duck.materialise(table, rel, values)
                result = duck.frame(table)
                assert result.height > 0 or rel.startswith("kpis/"), rel  # compare real rows
                _verdict(polars, result, rel, values, ran_otherwise)
                checked.add(rel.split(PER_PHASE)[0])  # a file run per phase counts as the file
                polars.register(table, result)  # the next step reads DuckDB's rows on both engines
                if table == "crossing_pairs":
                    duck.register("encroachments", encroachments(duck))
                    polars.register("encroachments", duck.frame("encroachments"))
    finally:
        con.close()


@pytest.fixture(scope="module")
def drives(tmp_path_factory, ingested):
    tmp = tmp_path_factory.mktemp("polars")
    real = ingested.steps(tmp / "real.duckdb",
                          ("commonroad", [DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"]),
                          ("scenarionet", [DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0103.pkl"]))
    sumo = ingested(tmp / "sumo.duckdb", "sumo", [DATA / "sumo/junction_s1"])
    return real, sumo


def test_every_query_file_has_a_true_polars_verdict(drives, tmp_path):
    real, sumo = drives
    checked: set[str] = set()
    ran_otherwise: set[str] = set()
    _walk(real, ["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut", "cut_in_ahead_of_ego"], "auto",
          {"max_distance_from_cyclist": "6m"}, checked, ran_otherwise)
    _walk(sumo, [LEFT_TURN], "every:40", {}, checked, ran_otherwise)

    # ingest's staging query, over the tracks with the kinematics it derives taken out
    con = db.connect(real)
    try:
        raw = con.sql("select * from tracks order by drive_id, actor_id, frame").pl().with_columns(
            *(pl.lit(None, pl.Float64).alias(c) for c in ("heading_rad", "speed_mps", "accel_mps2")),
            track_no=pl.struct("drive_id", "actor_id").rle_id())  # as ingest gives it (ingestion.py)
        con.register("tracks_raw", raw)
        polars = PolarsEngine(con)
        polars.register("tracks_raw", raw)
        _verdict(polars, con.sql("select * from (" + query_text("staging/tracks.sql") + ")").pl(), "staging/tracks.sql",
                 {}, ran_otherwise)
        checked.add("staging/tracks.sql")
    finally:
        con.close()

    # the coverage histogram, over the samples and buckets a DuckDB run stored
    copy = tmp_path / "histogram.duckdb"
    shutil.copy(real, copy)
    match(copy, scenarios=["follower_vehicle"])
    con = db.connect(copy)
    try:
        polars = PolarsEngine(con)
        for table in ("coverage_samples", "coverage_buckets"):
            polars.register(table, con.sql(f"select * from {table}").pl())
        _verdict(polars, con.sql(query_text("coverage/histogram.sql")).pl(), "coverage/histogram.sql", {},
                 ran_otherwise)
        checked.add("coverage/histogram.sql")
    finally:
        con.close()

    queries = data_dir("queries")
    # every query file but the overrides and the replay's (the report and `replay` run those on the DuckDB file,
    # never an engine)
    every = {str(p.relative_to(queries)) for p in queries.rglob("*.sql")
             if p.parts[len(queries.parts)] not in ("overrides", "replay")}
    assert checked == every
    # every override was run against DuckDB's rows, and overrides only files that exist
    overrides = {str(p.relative_to(queries / "overrides/polars")) for p in (queries / "overrides/polars").rglob("*.sql")}
    assert overrides <= ran_otherwise and overrides <= every
    assert ran_otherwise == {"match/identify.sql"}


def test_engine_polars_stops_before_running_and_names_the_query(drives, monkeypatch):
    """A file the verdict table says Polars cannot run (none of the bundled scenarios' since the left turn became
    portable; a scenario of one's own may have one) stops the run before anything runs, naming the file."""
    _, sumo = drives
    monkeypatch.setitem(POLARS_UNSUPPORTED, "phases/unprotected_left_turn_frames.sql", "unsupported function 'x'")
    with pytest.raises(EngineError, match=r"engine='polars': queries/phases/unprotected_left_turn_frames\.sql cannot "
                                          r"run on Polars SQL: unsupported function 'x'"):
        match(sumo, scenarios=[LEFT_TURN], engine="polars")


def test_engine_spark_without_pyspark_says_how_to_install(monkeypatch):
    import sys

    from logiq_sql.engines.spark_engine import spark_session

    monkeypatch.setitem(sys.modules, "pyspark.sql", None)  # as if PySpark were not installed
    with pytest.raises(EngineError, match=re.escape("pip install 'logiq-sql[spark]'")):
        spark_session()


def test_render_has_no_polars_form():
    from logiq_sql.matching.match import render

    with pytest.raises(EngineError, match="Polars SQL has no parameters"):
        render("follower_vehicle", engine="polars")


def test_cli_engine_polars_is_a_clear_error(drives, capsys, monkeypatch):
    from logiq_sql.cli import main

    _, sumo = drives
    monkeypatch.setitem(POLARS_UNSUPPORTED, "phases/unprotected_left_turn_frames.sql", "unsupported function 'x'")
    assert main(["match", "--db", str(sumo), "--engine", "polars", "--scenario", LEFT_TURN, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--engine polars: queries/phases/unprotected_left_turn_frames.sql cannot run on Polars SQL" in err
    assert "Run this scenario on the duckdb or spark engine" in err


def test_select_drives_narrows_the_per_drive_tables_to_the_batch(drives):
    """A match batch's queries read only its drives' rows (Engine.select_drives), on DuckDB and on Polars, and
    release_drives gives the whole tables back."""
    real, _ = drives
    con = db.connect(real)
    try:
        everything = {t: con.sql(f"select drive_id, count(*) as n from {t} group by drive_id order by drive_id").pl()
                      for t in ("tracks", "track_lanes")}
        assert everything["tracks"].height == 2
        batch = pl.DataFrame({"drive_id": ["scene-0103"]})
        con.register("run_drives", batch)
        polars = PolarsEngine(con)
        polars.register("run_drives", batch)  # DuckDB reads the frame registered on its connection
        for engine in (DuckEngine(con), polars):
            engine.select_drives()
            for table, counts in everything.items():
                got = engine.frame(f"select drive_id, count(*) as n from {table} group by drive_id")
                assert got.rows() == counts.filter(pl.col("drive_id") == "scene-0103").rows(), (engine.name, table)
            engine.release_drives()
            for table, counts in everything.items():
                got = engine.frame(f"select drive_id, count(*) as n from {table} group by drive_id order by drive_id")
                assert got.rows() == counts.rows(), (engine.name, table)
    finally:
        con.close()


def test_the_duckdb_engine_copies_a_batch_s_inputs_only_before_shared_steps(drives):
    """A batch's per-drive inputs are temp views of its rows; only a step run with ``shared`` (the relation and
    junction steps, ``prepare_relations``) copies the ones it reads into temp tables first: a re-match whose
    computed steps read a few rows copies nothing."""
    real, _ = drives
    con = db.connect(real)
    kinds_sql = ("select table_name, 'table' from duckdb_tables() where temporary and table_name in ('tracks', "
                 "'track_lanes') union all select view_name, 'view' from duckdb_views() where temporary and "
                 "view_name in ('tracks', 'track_lanes')")
    try:
        con.register("run_drives", pl.DataFrame({"drive_id": ["scene-0103"]}))
        engine = DuckEngine(con)
        engine.select_drives()
        values = {"ego_mode": "all", "ego_every": 1, "ego_actor_ids_csv": ",", "ego_kinds_csv": ",vehicle,"}
        engine.materialise("egos", "relations/egos.sql", values)  # reads tracks, not a shared step
        assert dict(con.execute(kinds_sql).fetchall()) == {"tracks": "view", "track_lanes": "view"}
        engine.shared = True
        engine.materialise("egos", "relations/egos.sql", values)
        assert dict(con.execute(kinds_sql).fetchall()) == {"tracks": "table", "track_lanes": "view"}
        assert engine.frame("select distinct drive_id from tracks")["drive_id"].to_list() == ["scene-0103"]
        engine.release_drives()
        assert con.execute(kinds_sql).fetchall() == []
    finally:
        con.close()


OUTPUTS = {  # table -> sort key: every output table the matcher writes, except the run log
    "matches": ["match_id"],
    "match_phases": ["match_id", "phase_index"],
    "kpis": ["match_id"],
    "coverage_samples": ["match_id", "item"],
    "coverage": ["scenario", "item", "bucket"],
    "drive_scenarios": ["drive_id", "scenario"],
    "relations": ["drive_id", "ego_id", "actor_id", "frame"],
    "ego_lanes": ["drive_id", "ego_id", "frame"],
}


def _stored(path: Path, table: str) -> pl.DataFrame:
    con = db.connect(path)
    try:
        frame = con.sql(f"select * from {table}").pl()
    finally:
        con.close()
    return frame.drop("run_id", strict=False).sort(OUTPUTS[table], nulls_last=True)


def _both_engines(source: Path, tmp: Path, runs: list[dict]) -> dict[str, Path]:
    """Copies of an ingested file, each matched with the same runs by one engine."""
    copies = {engine: tmp / f"{engine}.duckdb" for engine in ("duckdb", "polars")}
    for engine, path in copies.items():
        shutil.copy(source, path)
        for kwargs in runs:
            match(path, engine=engine, keep=True, **kwargs)  # the kept tables are compared too
    return copies


def _assert_same_outputs(copies: dict[str, Path], scenarios: list[str]) -> None:
    matched = _stored(copies["duckdb"], "matches").group_by("scenario").len().sort("scenario")
    assert matched["scenario"].to_list() == scenarios  # every scenario has matches to compare
    for table in OUTPUTS:
        _same_rows(_stored(copies["duckdb"], table), _stored(copies["polars"], table), table)


def test_engine_polars_gives_duckdbs_results(drives, tmp_path):
    """The three scenarios that need no Polars-less file, as in the Spark parity test: NGSIM US-101 (every 4th car
    the SUT) and nuScenes scene-0103 (the cyclist within 6 m), matched incrementally in two groups and one drive
    per batch; every output table equal to DuckDB's, floats within 1e-9 relative."""
    real, _ = drives
    six_m = {"max_distance_from_cyclist": "6m"}
    copies = _both_engines(real, tmp_path, [
        dict(scenarios=["cyclist_close_to_moving_sut"], overrides=six_m, ego="every:4", drives=["scene-0103"]),
        dict(scenarios=["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut"], overrides=six_m,
             ego="every:4", batch_rows=1)])
    _assert_same_outputs(copies, ["cyclist_close_to_moving_sut", "follower_vehicle", "sut_cut_out"])


def test_engine_polars_gives_duckdbs_results_on_a_sumo_motorway(tmp_path):
    """The bundled SUMO motorway run, every 20th vehicle as the SUT: followers and cut-outs."""
    source = tmp_path / "motorway.duckdb"
    ingest("sumo", [DATA / "sumo/motorway_s1"], source)
    copies = _both_engines(source, tmp_path, [
        dict(scenarios=["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut"], ego="every:20")])
    _assert_same_outputs(copies, ["follower_vehicle", "sut_cut_out"])


def test_engine_polars_gives_duckdbs_results_on_the_left_turn(drives, tmp_path):
    """The bundled SUMO junction, every 40th vehicle the SUT: the left turn (encroachment areas from shapely, the
    phases in Polars SQL) as the Spark parity test runs it."""
    _, sumo = drives
    copies = _both_engines(sumo, tmp_path, [dict(scenarios=[LEFT_TURN], ego="every:40")])
    _assert_same_outputs(copies, [LEFT_TURN])


def test_the_lint_knows_which_files_have_a_polars_override(tmp_path):
    """A construct Polars SQL cannot run is a lint problem in a portable file, unless the file has a Polars
    override or the engine refuses it by name; an override must replace an existing file, bind the same
    parameters and itself run on Polars."""
    from logiq_sql.cli.lint import lint_tree

    root = tmp_path / "queries"
    (root / "relations").mkdir(parents=True)
    (root / "relations/runs.sql").write_text(
        "-- reads: t\n-- params: $min_frame\n"
        "select last_value(x ignore nulls) over (partition by a order by f rows between unbounded preceding and "
        "current row) as y from t where f > $min_frame")
    assert lint_tree(root) == [
        "queries/relations/runs.sql: last_value/first_value(... ignore nulls) does not run on Polars; take the running "
        "max of the frame that has a value and join back"]
    polars = root / "overrides/polars/relations"
    polars.mkdir(parents=True)
    (polars / "runs.sql").write_text("select max(x) over (partition by a order by f rows between unbounded preceding "
                                     "and current row) as y from t where f > $min_frame")
    assert lint_tree(root) == []
    (polars / "runs.sql").write_text("select bool_or(x) as y from t")
    (polars / "gone.sql").write_text("select 1 as y")
    assert lint_tree(root) == [
        "queries/overrides/polars/relations/gone.sql: overrides queries/relations/gone.sql, which does not exist; "
        "remove it",
        "queries/overrides/polars/relations/runs.sql: bool_or() does not run on Polars; use max(case when ... then 1 "
        "else 0 end) = 1",
        "queries/overrides/polars/relations/runs.sql: binds [], but queries/relations/runs.sql binds ['min_frame']; an "
        "override takes the same parameters"]
