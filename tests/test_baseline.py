"""The per-pair baseline of the benchmarks (benchmarks/baseline.py) finds exactly the SQL matcher's matches, so
the ratio the tier-S benchmark prints compares two implementations of the same thing."""

from __future__ import annotations

import sys
from pathlib import Path

import polars as pl
import pytest

from logiq_sql.ingestion import ingest
from logiq_sql.match import match

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
NGSIM = DATA / "commonroad_ngsim" / "scenarios_2018b"
CYCLIST = {"max_distance_from_cyclist": "6m"}  # the bundled nuScenes cyclist passes 5.2 m from the ego


@pytest.fixture(scope="module")
def matched(tmp_path_factory):
    sys.path.insert(0, str(ROOT))
    from benchmarks import baseline

    db = tmp_path_factory.mktemp("baseline") / "b.duckdb"
    ingest("commonroad", sorted(NGSIM.glob("USA_US101-*"))[:6] + sorted(NGSIM.glob("USA_Lanker-*"))[:4], db)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet"], db)
    result = match(db, list(baseline.BASELINES), ego="every:10", overrides=CYCLIST)
    return result.matches, baseline.run(db, CYCLIST)


@pytest.mark.parametrize("scenario", ["follower_vehicle", "cyclist_close_to_moving_sut"])
def test_baseline_finds_the_same_matches(matched, scenario):
    ours, theirs = matched
    keys = ["drive_id", "ego_id", "actor_id", "start_frame", "end_frame"]
    sql = set(ours.filter(pl.col("scenario") == scenario).select(keys).iter_rows())
    per_pair = {(r.drive_id, r.ego_id, r.actor_id, int(r.start_frame), int(r.end_frame))
                for r in theirs[scenario].itertuples()}
    assert sql, "the sample must have matches for the comparison to mean something"
    assert per_pair == sql
