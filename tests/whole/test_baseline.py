"""The per-pair baseline of the benchmarks (benchmarks/baseline.py) finds exactly the SQL matcher's matches, so
the ratio the tier-S benchmark prints compares two implementations of the same thing."""

from __future__ import annotations

import sys
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.match import match
from tests.helpers import intervals

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
NGSIM = DATA / "commonroad_ngsim" / "scenarios_2018b"
# the bundled nuScenes cyclist passes 5.2 m from the ego
CYCLIST_6M = {"max_distance_from_cyclist": "6m"}


@pytest.fixture(scope="module")
def matched(tmp_path_factory):
    sys.path.insert(0, str(ROOT))
    from benchmarks import baseline

    db = tmp_path_factory.mktemp("baseline") / "b.duckdb"
    ingest("commonroad", sorted(NGSIM.glob("USA_US101-*"))[:6] + sorted(NGSIM.glob("USA_Lanker-*"))[:4], db)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet"], db)
    # the meaning the baseline implements (max_gap 0: a phase ends at every missing frame) on both sides
    overrides = {**CYCLIST_6M, **baseline.SAME_MEANING}
    result = match(db, scenarios=list(baseline.BASELINES), ego="every:10", overrides=overrides)
    return result.matches, baseline.run(db, overrides)


@pytest.mark.parametrize("scenario", ["follower_vehicle", "cyclist_close_to_moving_sut"])
def test_baseline_finds_the_same_matches(matched, scenario):
    ours, theirs = matched
    keys = ["drive_id", "ego_id", "actor_id", "start_frame", "end_frame"]
    sql = set(ours.filter(pl.col("scenario") == scenario).select(keys).iter_rows())
    per_pair = {(r.drive_id, r.ego_id, r.actor_id, int(r.start_frame), int(r.end_frame))
                for r in theirs[scenario].itertuples()}
    assert sql, "the sample must have matches for the comparison to mean something"
    assert per_pair == sql


def _phase_cases() -> list[str]:
    from tests.matching import test_phases

    return sorted(name for name in dir(test_phases) if name.startswith("test_"))


@pytest.mark.parametrize("case", _phase_cases())
def test_baseline_agrees_on_the_hand_made_phase_cases(case, tmp_path, monkeypatch):
    """Every hand-made case of tests/matching/test_phases.py, run again with the baseline beside the SQL matcher:
    wherever a case matches follower_vehicle or cyclist_close_to_moving_sut, both find the same matches under the
    meaning the baseline implements (the case's own overrides and baseline.SAME_MEANING). Each rule the SQL gains
    with a case (a sharp turn, lanes that overlap) fails here until the baseline reads it the same way."""
    sys.path.insert(0, str(ROOT))
    from benchmarks import baseline
    from tests.matching import test_phases

    keys = ["drive_id", "ego_id", "actor_id", "start_frame", "end_frame"]
    compared = []

    def run_both(db, scenario, **kw):
        found = intervals(match(db, scenarios=[scenario], **kw).matches, scenario)
        if scenario in baseline.BASELINES:
            overrides = {**kw.pop("overrides", {}), **baseline.SAME_MEANING}
            ours = match(db, scenarios=[scenario], overrides=overrides, force=True, **kw).matches
            theirs = baseline.run(db, overrides)[scenario]
            assert set(ours.filter(pl.col("scenario") == scenario).select(keys).iter_rows()) == {
                (r.drive_id, r.ego_id, r.actor_id, int(r.start_frame), int(r.end_frame)) for r in theirs.itertuples()}
            compared.append(scenario)
        return found

    monkeypatch.setattr(test_phases, "run", run_both)
    getattr(test_phases, case)(tmp_path)
    if not compared:
        pytest.skip("the case matches neither of the baseline's scenarios")


def test_component_parts_count_what_the_pipeline_computes(tmp_path):
    """benchmarks/components.py: every part runs on a tier's Parquet, its pair join counts what a brute-force
    cross join per frame counts (every 10th actor of a drive by id, every other actor within 200 m), and its
    localisation finds as many (row, lane) pairs as ingest's localisation stored."""
    sys.path.insert(0, str(ROOT))
    from benchmarks import components

    db = tmp_path / "c.duckdb"
    ingest("commonroad", sorted(NGSIM.glob("USA_US101-*"))[:2], db)
    tracks = tmp_path / "tracks.parquet"
    with duckdb.connect(str(db), read_only=True) as con:
        con.execute(f"copy (select * from tracks) to '{tracks}' (format parquet)")
        con.execute(f"copy (select * from drive_inputs) to '{tmp_path / 'drives.parquet'}' (format parquet)")
        con.execute(f"copy (select * from lanes) to '{tmp_path / 'lanes.parquet'}' (format parquet)")
        counted = con.execute(components.PARTS["pair join"], {"path": str(tracks)}).fetchone()[0]
        (stored,) = con.execute("select count(*) from track_lanes").fetchone()
    rows = pl.read_parquet(tracks).select("drive_id", "actor_id", "frame", "x_m", "y_m")
    tenth = (rows.select("drive_id", "actor_id").unique().sort("drive_id", "actor_id")
             .with_columns(n=pl.int_range(pl.len()).over("drive_id")).filter(pl.col("n") % 10 == 0))
    egos = rows.join(tenth.select("drive_id", "actor_id"), on=["drive_id", "actor_id"])
    pairs = egos.join(rows, on=["drive_id", "frame"], suffix="_a").filter(
        (pl.col("actor_id") != pl.col("actor_id_a"))
        & ((pl.col("x_m_a") - pl.col("x_m")) ** 2 + (pl.col("y_m_a") - pl.col("y_m")) ** 2 <= 200.0 ** 2))
    assert counted == pairs.height > 0
    assert components.localisation(tracks) == stored > 0
    assert set(components.measure(tracks)) == {*components.PARTS, "localisation"}
    # the lanes write writes every stored track_lanes row, as stored
    lanes_parquet = tmp_path / "track_lanes.parquet"
    with duckdb.connect(str(db), read_only=True) as con:
        con.execute(f"copy track_lanes to '{lanes_parquet}' (format parquet)")
    with duckdb.connect(str(tmp_path / "part.duckdb")) as con:
        con.execute(components.LANES_WRITE, {"path": str(lanes_parquet)})
        con.execute(f"attach '{db}' as ingested (read_only)")
        assert con.execute("select count(*) from (select * from track_lanes except all "
                           "select * from ingested.track_lanes)").fetchone()[0] == 0
        assert con.execute("select count(*) from track_lanes").fetchone()[0] == stored
