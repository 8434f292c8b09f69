"""Polars SQL against DuckDB, query file by query file, so the verdict table (engines.POLARS_UNSUPPORTED) cannot
rot: a query it does not list must give DuckDB's rows over the same inputs; a query it lists must fail with the
listed error. And --engine polars stops, naming the query file and the reason, before it runs anything.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import polars as pl
import pytest

from logiq_sql import db, ingest, match
from logiq_sql.encroachment import encroachments
from logiq_sql.engines import POLARS_UNSUPPORTED, DuckEngine, EngineError, PolarsEngine
from logiq_sql.match import select_run_drives
from logiq_sql.plan import SAMPLES_QUERY, parse_ego, resolve_scenarios, run_values, scenario_steps
from logiq_sql.paths import data_dir
from logiq_sql.sql import query_text

DATA = Path(__file__).parent / "data"
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


def _verdict(polars: PolarsEngine, duck: pl.DataFrame, relative: str, values: dict[str, object]) -> None:
    if relative in POLARS_UNSUPPORTED:
        with pytest.raises(Exception, match=re.escape(POLARS_UNSUPPORTED[relative])):
            polars.run(relative, values)
    else:
        _same_rows(duck, polars.run(relative, values), relative)


def _walk(path: Path, scenarios: list[str], ego: str, overrides: dict[str, str], checked: set[str]) -> None:
    """Every step of the scenarios on DuckDB; each query file also on Polars over DuckDB's inputs to it."""
    con = db.connect(path)
    try:
        run_drives = select_run_drives(con, None)
        con.register("run_drives", run_drives)
        duck, polars = DuckEngine(con), PolarsEngine(con)
        polars.register("run_drives", run_drives)
        for s in resolve_scenarios(scenarios, overrides):
            values = run_values(s, parse_ego(ego), 200.0)
            steps = [*scenario_steps(s), ("scenario_matches", "match/identify.sql"),
                     *[("_kpi", rel) for rel in s.kpi_queries], ("match_samples", SAMPLES_QUERY),
                     *[("_sample", rel) for rel in s.sample_queries]]
            for table, rel in steps:
                duck.materialise(table, rel, values)
                result = duck.frame(table)
                # compare real rows (no_phase.sql stands in for unused phase slots: never any)
                assert result.height > 0 or rel.startswith("kpis/") or rel == "match/no_phase.sql", rel
                _verdict(polars, result, rel, values)
                checked.add(rel)
                polars.register(table, result)  # the next step reads DuckDB's rows on both engines
                if table == "crossing_pairs":
                    duck.register("encroachments", encroachments(duck))
                    polars.register("encroachments", duck.frame("encroachments"))
    finally:
        con.close()


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("polars")
    real, sumo = tmp / "real.duckdb", tmp / "sumo.duckdb"
    ingest("commonroad", [DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"], real)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0103.pkl"], real)
    ingest("sumo", [DATA / "sumo/junction_s1"], sumo)
    return real, sumo


def test_every_query_file_has_a_true_polars_verdict(drives, tmp_path):
    real, sumo = drives
    checked: set[str] = set()
    _walk(real, ["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut", "cut_in_ahead_of_ego"], "auto",
          {"max_distance_from_cyclist": "6m"}, checked)
    _walk(sumo, [LEFT_TURN], "every:40", {}, checked)

    # ingest's staging query, over the tracks with the kinematics it derives taken out
    con = db.connect(real)
    try:
        raw = con.sql("select * from tracks").pl().with_columns(
            pl.lit(None, pl.Float64).alias(c) for c in ("heading_rad", "speed_mps", "accel_mps2"))
        con.register("tracks_raw", raw)
        polars = PolarsEngine(con)
        polars.register("tracks_raw", raw)
        _verdict(polars, con.sql("select * from (" + query_text("staging/tracks.sql") + ")").pl(), "staging/tracks.sql",
                 {})
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
        _verdict(polars, con.sql(query_text("coverage/histogram.sql")).pl(), "coverage/histogram.sql", {})
        checked.add("coverage/histogram.sql")
    finally:
        con.close()

    every = {str(p.relative_to(data_dir("queries"))) for p in data_dir("queries").rglob("*.sql")}
    assert checked == every


def test_engine_polars_stops_before_running_and_names_the_query(drives):
    real, _ = drives
    with pytest.raises(EngineError, match=r"--engine polars: queries/relations/ego_lanes\.sql cannot run on Polars "
                                          r"SQL: unexpected clause found in 'LAST_VALUE' \(IGNORE NULLS\)"):
        match(real, scenarios=["cyclist_close_to_moving_sut"], engine="polars")


def test_engine_spark_without_pyspark_says_how_to_install(monkeypatch):
    import sys

    from logiq_sql.engines import spark_session

    monkeypatch.setitem(sys.modules, "pyspark.sql", None)  # as if PySpark were not installed
    with pytest.raises(EngineError, match=re.escape("pip install 'logiq-sql[spark]'")):
        spark_session()


def test_render_has_no_polars_form():
    from logiq_sql.match import render

    with pytest.raises(EngineError, match="Polars SQL has no parameters"):
        render("follower_vehicle", engine="polars")


def test_cli_engine_polars_is_a_clear_error(drives, capsys):
    from logiq_sql.cli import main

    real, _ = drives
    assert main(["match", "--db", str(real), "--engine", "polars", "--scenario", "follower_vehicle", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--engine polars: queries/relations/ego_lanes.sql cannot run on Polars SQL" in err
    assert "--engine duckdb or spark" in err


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
