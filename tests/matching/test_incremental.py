"""Scheduled runs: matching is incremental and idempotent, and every parameter set is recorded with its matches."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import ingest, match
from logiq_sql.core import sql

ROOT = Path(__file__).resolve().parents[2]
NGSIM = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b"
FIRST = [NGSIM / "USA_US101-22_1_T-1.xml.gz", NGSIM / "USA_US101-26_1_T-1.xml.gz"]
LATER = NGSIM / "USA_US101-24_1_T-1.xml.gz"
SCENARIOS = ["follower_vehicle", "sut_cut_out"]
TABLES = ("matches", "match_phases", "kpis", "coverage", "coverage_samples", "drive_scenarios", "match_runs",
          "ego_lanes", "drives")  # ego_lanes: the kept table every run stores (relations only with keep)


def snapshot(db: Path) -> dict[str, pl.DataFrame]:
    """Every output table, rows sorted on all columns, so two snapshots compare regardless of storage order."""
    with duckdb.connect(str(db), read_only=True) as con:
        frames = {t: con.sql(f"select * from {t}").pl() for t in TABLES}
    return {t: f.sort(f.columns, nulls_last=True) for t, f in frames.items()}


def assert_same(a: dict[str, pl.DataFrame], b: dict[str, pl.DataFrame], skip: tuple[str, ...] = ()) -> None:
    for table in TABLES:
        if table not in skip:
            assert a[table].equals(b[table]), table


@pytest.fixture(scope="module")
def first_run_once(tmp_path_factory, ingested) -> Path:
    """FIRST ingested and matched once for the module; each test gets its own copy (first_run)."""
    db = ingested(tmp_path_factory.mktemp("first_run") / "x.duckdb", "commonroad", FIRST)
    match(db, scenarios=SCENARIOS)
    return db


@pytest.fixture
def first_run(tmp_path, first_run_once) -> Path:
    db = tmp_path / "x.duckdb"
    shutil.copyfile(first_run_once, db)
    return db


def test_rerunning_the_same_drives_changes_nothing(first_run):
    before = snapshot(first_run)
    result = match(first_run, scenarios=SCENARIOS)
    assert result.up_to_date == {"follower_vehicle": 2, "sut_cut_out": 2}
    assert "already up to date" in result.summary()
    after = snapshot(first_run)
    assert_same(before, after)
    assert before["match_runs"].height == 2  # one row per scenario of the first run, none for the skipped rerun
    assert after["matches"]["match_id"].is_unique().all()
    assert after["matches"].height > 0 and result.matches.height == after["matches"].height


def test_force_reruns_and_finds_the_same_matches(first_run):
    before = snapshot(first_run)
    result = match(first_run, scenarios=SCENARIOS, force=True)
    assert result.up_to_date == {"follower_vehicle": 0, "sut_cut_out": 0}
    after = snapshot(first_run)
    # same matches, phases, KPIs and coverage; only the run that produced them is new
    drop_run = {t: f.drop("run_id", strict=False) for t, f in before.items()}
    assert_same(drop_run, {t: f.drop("run_id", strict=False) for t, f in after.items()}, skip=("match_runs",))
    assert after["match_runs"].height == 4
    assert after["matches"]["run_id"].n_unique() == 1
    assert after["matches"]["run_id"][0] == after["match_runs"]["run_id"].max()


def test_a_new_drive_is_appended_and_the_others_are_not_rerun(first_run):
    before = snapshot(first_run)
    ingest("commonroad", [LATER], first_run)
    result = match(first_run, scenarios=SCENARIOS)
    assert result.up_to_date == {"follower_vehicle": 2, "sut_cut_out": 2}
    after = snapshot(first_run)
    new = "USA_US101-24_1_T-1@2018b"
    old_matches = after["matches"].filter(pl.col("drive_id") != new)
    assert old_matches.equals(before["matches"])
    assert after["matches"].filter(pl.col("drive_id") == new).height > 0
    assert after["matches"]["match_id"].is_unique().all()
    latest = after["match_runs"].filter(pl.col("run_id") == pl.col("run_id").max())
    assert latest.select("scenario", "drives").sort("scenario").rows() == [("follower_vehicle", 1), ("sut_cut_out", 1)]
    assert latest["matches"].sum() == after["matches"].filter(pl.col("drive_id") == new).height
    # the drives of the run are reported whole: the two up to date and the new one
    assert sorted(result.drives["drive_id"]) == sorted([*before["drives"]["drive_id"], new])


def test_a_changed_parameter_is_recorded_with_the_matches_it_produced(first_run):
    before = snapshot(first_run)
    result = match(first_run, scenarios=SCENARIOS, overrides={"same_road_limit": "5s"})  # follower_vehicle's
    assert result.up_to_date == {"follower_vehicle": 0, "sut_cut_out": 2}
    after = snapshot(first_run)
    run = after["match_runs"].filter(pl.col("run_id") == pl.col("run_id").max())
    assert run["scenario"].to_list() == ["follower_vehicle"]
    assert json.loads(run["overrides"].item()) == {"same_road_limit": "5s"}
    assert json.loads(run["params_json"].item())["same_road_limit_s"] == 5.0
    followers = after["matches"].filter(pl.col("scenario") == "follower_vehicle")
    assert followers.height == run["matches"].item() == result.matches.filter(
        pl.col("scenario") == "follower_vehicle").height
    assert followers["params_hash"].unique().to_list() == run["params_hash"].to_list()
    # the earlier follower matches were replaced, not duplicated; the cut-outs were left alone
    assert after["matches"]["match_id"].is_unique().all()
    cut_outs = [f.filter(pl.col("scenario") == "sut_cut_out") for f in (before["matches"], after["matches"])]
    assert cut_outs[0].height > 0 and cut_outs[0].equals(cut_outs[1])
    # the analyst's join: every match names the run and the parameter values that produced it
    with duckdb.connect(str(first_run), read_only=True) as con:
        joined = con.sql("select m.scenario, m.params_hash, r.params_hash as run_hash, "
                         "json_extract(r.params_json, '$.same_road_limit_s')::double as same_road_limit_s "
                         "from matches m join match_runs r using (run_id, scenario)").pl()
    assert joined.height == after["matches"].height
    assert (joined["params_hash"] == joined["run_hash"]).all()
    assert joined.filter(pl.col("scenario") == "follower_vehicle")["same_road_limit_s"].unique().to_list() == [5.0]


def test_reingesting_a_drive_makes_the_next_run_match_it_again(first_run):
    drive = FIRST[0].name.split(".")[0]

    def rows_of_drive() -> dict[str, int]:
        with duckdb.connect(str(first_run), read_only=True) as con:
            return {t: con.execute(f"select count(*) from {t} where drive_id like $d", {"d": drive + "%"}
                                   ).fetchall()[0][0] for t in ("matches", "drive_scenarios", "ego_lanes")}

    assert rows_of_drive()["matches"] > 0
    ingest("commonroad", [FIRST[0]], first_run)
    # its old matches and kept tables went with its old rows: nothing stale until the next match
    assert rows_of_drive() == {"matches": 0, "drive_scenarios": 0, "ego_lanes": 0}
    result = match(first_run, scenarios=SCENARIOS)
    assert rows_of_drive()["matches"] > 0
    assert result.up_to_date == {"follower_vehicle": 1, "sut_cut_out": 1}


def test_scenarios_with_different_drives_to_match_keep_every_kept_table_unique(tmp_path):
    """Two groups in one run (left turn on two junction drives, follower only on the new one): each group keeps
    only the junction tables it computed."""
    runs = tmp_path / "runs"
    for name in ("j1", "j2"):
        shutil.copytree(Path(__file__).parents[1] / "data/sumo/junction_s1", runs / name)
    db = tmp_path / "x.duckdb"
    ingest("sumo", [runs / "j1"], db)
    match(db, scenarios=["follower_vehicle"], ego="every:5")
    ingest("sumo", [runs / "j2"], db)
    result = match(db, scenarios=["unprotected_left_turn_with_yield_and_traffic_light", "follower_vehicle"],
                   ego="every:5", keep=True)
    assert result.up_to_date == {"unprotected_left_turn_with_yield_and_traffic_light": 0, "follower_vehicle": 1}
    with duckdb.connect(str(db), read_only=True) as con:
        passages = con.sql("select drive_id, actor_id, passage from passages").pl()
        encroachments = con.sql("select drive_id, ego_id, ego_passage, actor_id, actor_passage from encroachments").pl()
        relations = con.sql("select drive_id, ego_id, actor_id, frame from relations").pl()
    assert passages.height > 0 and set(passages["drive_id"]) == {"j1", "j2"}
    assert not passages.is_duplicated().any()
    assert encroachments.height > 0 and not encroachments.is_duplicated().any()
    assert not relations.is_duplicated().any()


def test_matching_in_batches_of_drives_gives_the_same_outputs(tmp_path, ingested):
    """Large files are matched a few drives at a time (memory stays bounded); one drive per batch must give what
    one pass over every drive gives, and match_runs still has one row per run and scenario."""
    dbs = {}
    for name, batch_rows in (("one_pass", 10**9), ("per_drive", 1)):
        db = dbs[name] = ingested(tmp_path / f"{name}.duckdb", "commonroad", [*FIRST, LATER])
        match(db, scenarios=SCENARIOS, batch_rows=batch_rows)
    one_pass, per_drive = snapshot(dbs["one_pass"]), snapshot(dbs["per_drive"])
    run_specific = ("run_id", "started_at")
    for table in TABLES:
        a, b = (s[table].drop([c for c in run_specific if c in s[table].columns]) for s in (one_pass, per_drive))
        assert a.equals(b), table
    runs = per_drive["match_runs"]
    assert runs.height == len(SCENARIOS) and (runs["drives"] == 3).all()
    assert runs.sort("scenario")["matches"].to_list() == (
        per_drive["matches"].group_by("scenario").len().sort("scenario")["len"].to_list())


def test_an_edited_query_reruns_its_drives_at_the_same_scenario_version(ingested, tmp_path):
    """An analyst edits a phase query and reruns without bumping the version: the drives are matched again with the
    edited SQL (match_runs.queries_hash), not skipped as up to date with the old matches."""
    db = ingested(tmp_path / "x.duckdb", "commonroad", FIRST)
    folder = tmp_path / "mine"
    (folder / "phases").mkdir(parents=True)
    shutil.copy(ROOT / "scenarios/follower_vehicle.toml", folder)
    query = folder / "phases/follower_vehicle.sql"
    original = (ROOT / "queries/phases/follower_vehicle.sql").read_text()
    query.write_text(original)
    match(db, scenarios=["follower_vehicle"], scenario_path=folder)
    before = snapshot(db)
    # a follower only within half the maximum headway: fewer or shorter matches
    changed = original.replace("<= $max_distance_from_sut_in_time_units_s", "<= $max_distance_from_sut_in_time_units_s / 2")
    assert changed != original
    query.write_text(changed)
    sql.query_text.cache_clear()  # a new process would read the file again
    result = match(db, scenarios=["follower_vehicle"], scenario_path=folder)
    assert result.up_to_date == {"follower_vehicle": 0}
    after = snapshot(db)
    assert not after["matches"].drop("run_id").equals(before["matches"].drop("run_id"))
    forced = tmp_path / "forced.duckdb"
    shutil.copyfile(db, forced)
    match(forced, scenarios=["follower_vehicle"], scenario_path=folder, force=True)
    sql.query_text.cache_clear()
    drop_run = {t: f.drop("run_id", "started_at", strict=False) for t, f in snapshot(forced).items()}
    assert_same(drop_run, {t: f.drop("run_id", "started_at", strict=False) for t, f in after.items()},
                skip=("match_runs",))
