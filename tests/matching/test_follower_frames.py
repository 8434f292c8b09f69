"""The follower's frames step (queries/phases/follower_vehicle_frames.sql): a match keeps only its rows where
``may_hold``, so ``may_hold`` must be true at every row that can hold, or that the phase reads, whatever the
parameters; and a re-match after a change of ``same_road_limit`` reuses the frames step from the step cache."""

from __future__ import annotations

from pathlib import Path

import pytest

from logiq_sql import match
from logiq_sql.core.sql import bind, materialise, query_text
from logiq_sql.matching.runner import kept_rows
from logiq_sql.spec.plan import RELATION_STEPS, parse_ego, resolve_scenarios, run_values
from logiq_sql.storage import db
from tests.helpers import EVERY_MAP

FRAMES = "phases/follower_vehicle_frames.sql"
PHASE = "phases/follower_vehicle.sql"


@pytest.fixture(scope="module")
def drives(tmp_path_factory, ingested) -> Path:
    # a motorway with lane changes and a junction with turns: the lanes the ego left and the lanes leaving its road
    return ingested.steps(tmp_path_factory.mktemp("follower_frames") / "x.duckdb", *EVERY_MAP)


def test_a_match_keeps_the_follower_frames_where_may_hold_and_every_phase_row_where_holds():
    (follower,) = resolve_scenarios(["follower_vehicle"], {})
    (left_turn,) = resolve_scenarios(["unprotected_left_turn_with_yield_and_traffic_light"], {})
    assert follower.frames_query == FRAMES
    assert kept_rows(follower, "scenario_frames") == "may_hold"
    assert kept_rows(follower, "phase_1") == "holds"
    assert kept_rows(left_turn, "scenario_frames") is None  # its frames step has no may_hold: every row is kept
    assert kept_rows(follower, "relations") is None


@pytest.mark.parametrize("same_road_limit_s", [1.0, 4.0, 10.0, 30.0])
def test_the_phase_holds_at_the_same_rows_over_the_frames_that_may_hold(drives, same_road_limit_s):
    (follower,) = resolve_scenarios(["follower_vehicle"], {})
    values = run_values(follower, parse_ego("every:1"), 200.0) | {"same_road_limit_s": same_road_limit_s}
    con = db.connect(drives, read_only=True)
    try:
        con.execute("create temp table run_drives as select drive_id from drive_inputs where status = 'ingested'")
        for table, rel in (("egos", "relations/egos.sql"), *RELATION_STEPS):
            materialise(con, table, rel, values)
        found = {}
        for kept in (None, "may_hold"):
            materialise(con, "scenario_frames", FRAMES, values, kept)
            frames = con.execute("select count(*) from scenario_frames").fetchall()[0][0]
            rows = con.execute(f"select * from ({query_text(PHASE)}) as step where holds order by all",
                               bind(PHASE, values)).fetchall()
            found[kept] = frames, rows
        (every, holding), (kept_frames, kept_holding) = found[None], found["may_hold"]
        assert holding, "the drives have followers to find"
        assert kept_frames < every / 2  # most frames behind the ego can never hold
        assert kept_holding == holding
    finally:
        con.close()


def test_a_same_road_limit_change_reuses_the_frames_step(drives, tmp_path, monkeypatch):
    monkeypatch.setenv("LOGIQ_SQL_STEP_CACHE", "all")  # every step kept, so which steps are reused is known
    copy = tmp_path / "copy.duckdb"
    copy.write_bytes(drives.read_bytes())
    match(copy, scenarios=["follower_vehicle"])
    result = match(copy, scenarios=["follower_vehicle"], overrides={"same_road_limit": "4sec"})
    status = {step: s for _batch, _owners, step, s in result.cache_steps}
    assert status[f"scenario_frames {FRAMES}"] == "reused"
    assert status[f"phase_1 {PHASE}"] == "computed"
