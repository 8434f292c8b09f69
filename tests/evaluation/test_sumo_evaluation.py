"""The accuracy targets of the realistic-manoeuvres issue, on SUMO drives nothing was tuned on, end to end:

simulate (gradual 3 s lane changes, trucks and buses, a 3-lane junction with creeping left-turners) -> label from
SUMO's records -> perceived copies (exact, and the issue's perception-like noise) -> ingest -> match with trucks
and buses among the egos -> evaluate (``logiq_sql.cli.campaign.score_drive``, the code behind the tables of
docs/evaluation.md). Event F1 >= 0.95 for follower_vehicle and sut_cut_out on a motorway drive and for
cyclist_close_to_moving_sut on a junction drive, >= 0.90 for the left turn; >= 0.90 for each with noise (0.2 m
position, 1 deg heading, 0.1 m/s speed, 2 % of detections dropped). Also logiq_sql's per-frame TTC against SUMO's
SSM minimum TTC of car-following pairs (on a drive of SUMO's instantaneous lane changes: SSM logs nothing
with gradual ones), and the speed and acceleration KPIs against the FCD values.

Seeds 950 and 951 are used here only (development: 100-199; the campaign's tables: 900-902).
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import match
from logiq_sql.cli import main
from logiq_sql.cli.campaign import CONFLICT_SCENARIO, NOISE, Setup, score_drive
from logiq_sql.core.units import factor
from logiq_sql.evaluation.crosscheck import read_ssm_following_ttc, ttc_against_ssm
from logiq_sql.evaluation.simulate import Regime
from logiq_sql.ingestion.readers.sumo import read_fcd
from logiq_sql.storage import db as logiq_db

pytestmark = pytest.mark.sumo
MOTORWAY_SEED, JUNCTION_SEED = 950, 951
LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"
TARGETS = {  # scenario -> (F1 on exact tracks, F1 with perception-like noise), from the issue
    "follower_vehicle": (0.95, 0.90), "sut_cut_out": (0.95, 0.90),
    "cyclist_close_to_moving_sut": (0.95, 0.90), LEFT_TURN: (0.90, 0.90),
}


def _drive(tmp_path_factory, name: str, setup: Setup, seed: int) -> tuple[Path, dict]:
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    out = tmp_path_factory.mktemp(name)
    scores = score_drive(out, name, setup, seed, NOISE, say=lambda _msg: None)
    return out, {(r["noise"], r["scenario"]): r for r in scores.iter_rows(named=True)}


@pytest.fixture(scope="module")
def motorway(tmp_path_factory):
    """4 minutes of the motorway (3 s lane changes, 15 % trucks, 5 % coaches); every truck and coach and every
    4th car is the SUT."""
    return _drive(tmp_path_factory, "motorway", Setup("motorway", Regime(), 4, 4), MOTORWAY_SEED)


@pytest.fixture(scope="module")
def junction(tmp_path_factory):
    """6 minutes of the 3-lane junction with creeping left-turners; every truck and bus, every 2nd car."""
    return _drive(tmp_path_factory, "junction", Setup("junction", Regime(approach_lanes=3), 6, 2), JUNCTION_SEED)


def _check(scores: dict, scenario: str, noise: str, least_labels: int) -> None:
    s = scores[(noise, scenario)]
    assert s["labels"] >= least_labels, s   # enough events for the score to mean something
    assert s["f1"] is not None and s["f1"] >= TARGETS[scenario][noise == "perception"], s


@pytest.mark.parametrize("noise", ["exact", "perception"])
@pytest.mark.parametrize("scenario", ["follower_vehicle", "sut_cut_out"])
def test_motorway_event_f1(motorway, scenario, noise):
    _check(motorway[1], scenario, noise, 20)


@pytest.mark.parametrize(("scenario", "noise"), [
    ("cyclist_close_to_moving_sut", "exact"), ("cyclist_close_to_moving_sut", "perception"),
    (LEFT_TURN, "exact"), (LEFT_TURN, "perception")])
def test_junction_event_f1(junction, scenario, noise):
    # the left turn credits the car each left-turner waited for before it set off (docs/semantics.md, phases 3
    # and 4): about one event per left-turning ego's wait, 9 on this drive
    _check(junction[1], scenario, noise, 8 if scenario == LEFT_TURN else 20)


@pytest.mark.parametrize("noise", ["exact", "perception"])
def test_junction_left_turn_f1_against_the_conflict_labels(junction, noise):
    """The same matches against the second labeller (conflict_labels.py: the vehicle the Ego waited for)."""
    s = junction[1][(noise, CONFLICT_SCENARIO)]
    assert s["labels"] >= 8 and s["f1"] is not None and s["f1"] >= TARGETS[LEFT_TURN][noise == "perception"], s


def test_trucks_and_buses_are_among_the_scored_egos(motorway):
    out, _ = motorway
    with duckdb.connect(str(out / "db" / f"motorway_s{MOTORWAY_SEED}_exact.duckdb"), read_only=True) as con:
        kinds = {k for (k,) in con.sql("select distinct t.kind from ego_lanes e join tracks t "
                                        "on t.drive_id = e.drive_id and t.actor_id = e.ego_id").fetchall()}
    assert {"vehicle", "truck", "bus"} <= kinds


@pytest.fixture(scope="module")
def ssm_run(tmp_path_factory) -> tuple[Path, Path]:
    """6 minutes of the motorway with SUMO's instantaneous lane changes: SUMO 1.28's SSM device logs no conflict
    at all once lane changes take time (0 against 12 in 2 minutes of seed 100), so the TTC cross-check needs
    this regime."""
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    root = tmp_path_factory.mktemp("ssm")
    run, db = root / "motorway_ssm", root / "ssm.duckdb"
    assert main(["simulate", "motorway", "--minutes", "6", "--seed", "952", "--lane-change-duration", "0",
                 "--out", str(run)]) == 0
    assert main(["ingest", "sumo", str(run), "--db", str(db), "--quiet"]) == 0
    return run, db


def test_following_ttc_agrees_with_sumo_ssm(ssm_run):
    run, db = ssm_run
    ssm = read_ssm_following_ttc(run / "ssm.xml.gz")
    assert ssm.height >= 10
    match(db, scenarios=["follower_vehicle"], ego=",".join(ssm["ego_id"].unique()), keep=True)
    con = logiq_db.connect(db)
    try:
        pairs = ttc_against_ssm(con, run.name, ssm)
    finally:
        con.close()
    within = (pairs["abs_error_s"] <= 0.05).sum()
    assert within >= 0.95 * pairs.height, pairs.filter(~(pl.col("abs_error_s") <= 0.05))


def test_speed_and_acceleration_kpis_equal_the_fcd_values(motorway):
    out, _ = motorway
    fcd = read_fcd(out / "runs" / f"motorway_s{MOTORWAY_SEED}" / "fcd.xml.gz").with_columns(
        frame=(pl.col("t_s") / 0.1).round().cast(pl.Int64))
    with duckdb.connect(str(out / "db" / f"motorway_s{MOTORWAY_SEED}_exact.duckdb"), read_only=True) as con:
        kpis = con.sql("""select m.ego_id, m.actor_id, m.start_frame, m.end_frame, k.*
                          from matches m join kpis k using (match_id)
                          where m.scenario = 'follower_vehicle'""").pl()
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
