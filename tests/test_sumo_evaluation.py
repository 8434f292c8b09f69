"""The issue-3 targets, measured on SUMO drives that nothing was tuned on (seed 11), through the CLI:

simulate -> ingest -> match -> label -> evaluate, event-level F1 >= 0.95 for follower_vehicle and sut_cut_out on a
motorway drive and for cyclist_close_to_moving_sut on a junction drive; logiq_sql's per-frame TTC against SUMO's
SSM minimum TTC of car-following pairs; speed and acceleration KPIs against the FCD values. The left turn
(unprotected_left_turn_with_yield_and_traffic_light) is scored on a junction drive of its own seed (21), with every
car as the SUT.
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import db as logiq_db
from logiq_sql import match
from logiq_sql.cli import main
from logiq_sql.evaluation.crosscheck import read_ssm_following_ttc, ttc_against_ssm
from logiq_sql.readers.sumo import read_fcd
from logiq_sql.units import factor

pytestmark = pytest.mark.sumo
SEED = "11"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    root = tmp_path_factory.mktemp("sumo_eval")
    for kind, minutes in (("motorway", "10"), ("junction", "15")):
        assert main(["simulate", kind, "--minutes", minutes, "--seed", SEED, "--out",
                     str(root / "runs" / kind)]) == 0
    db = root / "eval.duckdb"
    assert main(["ingest", "sumo", str(root / "runs"), "--db", str(db), "--quiet"]) == 0
    assert main(["match", "--db", str(db), "--ego", "every:10", "--quiet"]) == 0
    assert main(["label", "sumo", str(root / "runs"), "--out", str(root / "labels.parquet")]) == 0
    return root


def _scores(runs: Path, drive: str) -> dict[str, dict]:
    labels = pl.read_parquet(runs / "labels.parquet").filter(pl.col("drive_id") == drive)
    labels.write_parquet(runs / f"labels_{drive}.parquet")
    out = runs / f"eval_{drive}"
    assert main(["evaluate", "--db", str(runs / "eval.duckdb"), "--labels", str(runs / f"labels_{drive}.parquet"),
                 "--out", str(out)]) == 0
    return {r["scenario"]: r for r in pl.read_parquet(out / "evaluation.parquet").iter_rows(named=True)}


def test_event_f1_on_a_new_motorway_seed(runs):
    scores = _scores(runs, "motorway")
    for scenario in ("follower_vehicle", "sut_cut_out"):
        s = scores[scenario]
        assert s["labels"] >= 20, s          # enough events for the score to mean something
        assert s["f1"] >= 0.95, s


def test_event_f1_on_a_new_junction_seed(runs):
    s = _scores(runs, "junction")["cyclist_close_to_moving_sut"]
    assert s["labels"] >= 20, s
    assert s["f1"] >= 0.95, s


def test_following_ttc_agrees_with_sumo_ssm(runs):
    ssm = read_ssm_following_ttc(runs / "runs" / "motorway" / "ssm.xml.gz")
    assert ssm.height >= 20
    match(runs / "eval.duckdb", scenarios=["follower_vehicle"], ego=",".join(ssm["ego_id"].unique()),
          drives=["motorway"])
    con = logiq_db.connect(runs / "eval.duckdb")
    try:
        pairs = ttc_against_ssm(con, "motorway", ssm)
    finally:
        con.close()
    within = (pairs["abs_error_s"] <= 0.05).sum()
    assert within >= 0.95 * pairs.height, pairs.filter(~(pl.col("abs_error_s") <= 0.05))


def test_speed_and_acceleration_kpis_equal_the_fcd_values(runs):
    fcd = read_fcd(runs / "runs" / "motorway" / "fcd.xml.gz").with_columns(
        frame=(pl.col("t_s") / 0.1).round().cast(pl.Int64))
    with duckdb.connect(str(runs / "eval.duckdb"), read_only=True) as con:
        kpis = con.sql("""select m.ego_id, m.actor_id, m.start_frame, m.end_frame, k.*
                          from matches m join kpis k using (match_id)
                          where m.drive_id = 'motorway' and m.scenario = 'follower_vehicle'""").pl()
    assert kpis.height > 0
    mph = factor("mps") / factor("mph")
    for role, prefix in (("ego_id", "ego"), ("actor_id", "vehicle")):
        per_match = (kpis.select("match_id", role, "start_frame", "end_frame")
                     .join(fcd.rename({"vehicle_id": role}), on=role)
                     .filter(pl.col("frame").is_between("start_frame", "end_frame"))
                     .group_by("match_id")
                     .agg(fcd_max_speed=pl.col("speed_mps").max() * mph,
                          fcd_min_speed=pl.col("speed_mps").min() * mph,
                          fcd_max_accel=pl.col("accel_mps2").max(),
                          fcd_min_accel=pl.col("accel_mps2").min())
                     .join(kpis, on="match_id"))
        assert per_match.height == kpis.height
        for ours, theirs in ((f"{prefix}_max_speed_mph", "fcd_max_speed"), (f"{prefix}_min_speed_mph", "fcd_min_speed"),
                             (f"{prefix}_max_lon_acceleration_mpsps", "fcd_max_accel"),
                             (f"{prefix}_min_lon_acceleration_mpsps", "fcd_min_accel")):
            assert (per_match[ours] - per_match[theirs]).abs().max() < 1e-9, ours


LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"
LEFT_TURN_SEED = "21"  # nobody tuned the labeller or the matcher on it (development: seeds 1 and 11)


@pytest.fixture(scope="module")
def left_turn_run(tmp_path_factory) -> Path:
    """15 minutes of the junction, every car the SUT (about 30 s of matching), labelled from SUMO's records."""
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    root = tmp_path_factory.mktemp("sumo_left_turn")
    run, db = root / f"junction_s{LEFT_TURN_SEED}", root / "left_turn.duckdb"
    assert main(["simulate", "junction", "--minutes", "15", "--seed", LEFT_TURN_SEED, "--out", str(run)]) == 0
    assert main(["ingest", "sumo", str(run), "--db", str(db), "--quiet"]) == 0
    assert main(["match", "--db", str(db), "--scenario", LEFT_TURN, "--ego", "all", "--quiet"]) == 0
    assert main(["label", "sumo", str(run), "--scenario", LEFT_TURN, "--out", str(root / "labels.parquet")]) == 0
    assert main(["evaluate", "--db", str(db), "--labels", str(root / "labels.parquet"), "--out",
                 str(root / "eval")]) == 0
    return root


def test_left_turn_event_f1_on_a_new_junction_seed(left_turn_run):
    (s,) = pl.read_parquet(left_turn_run / "eval" / "evaluation.parquet").iter_rows(named=True)
    assert s["scenario"] == LEFT_TURN
    assert s["labels"] >= 100, s         # enough events for the score to mean something
    assert s["f1"] >= 0.9, s
