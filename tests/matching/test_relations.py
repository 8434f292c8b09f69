"""The ego-actor relation table: geometry against shapely, TTC/MTTC/headway against hand calculations."""

from __future__ import annotations

import duckdb
import numpy as np
import polars as pl
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from logiq_sql.matching.match import match
from tests.helpers import Y1, actor, example_dir, make_db, times


def relation_rows(db) -> pl.DataFrame:
    match(db, scenarios=["follower_vehicle"], keep=True)  # keep: the relation rows are read below
    with duckdb.connect(str(db), read_only=True) as con:
        return con.sql("select * from relations order by actor_id, frame").pl()


def box(x, y, h, length, width):
    c, s = np.cos(h), np.sin(h)
    pts = [(x + c * dx - s * dy, y + s * dx + c * dy)
           for dx, dy in ((length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2),
                          (length / 2, -width / 2))]
    return shapely.Polygon(pts)


BOXES = st.tuples(
    st.floats(-15, 15), st.floats(-15, 15), st.floats(-np.pi, np.pi), st.floats(0.5, 12), st.floats(0.4, 3)
)


def scene_rows(drive_id: str, ego, others) -> list[pl.DataFrame]:
    def row(actor_id, b, is_ego):
        return pl.DataFrame({"drive_id": drive_id, "actor_id": actor_id, "kind": "vehicle", "is_ego": is_ego,
                             "t_s": 0.0, "x_m": b[0], "y_m": b[1], "heading_rad": b[2], "speed_mps": 0.0,
                             "length_m": b[3], "width_m": b[4]})
    return [row("ego", ego, True)] + [row(f"a{i}", o, False) for i, o in enumerate(others)]


# each example is several scenes, one drive each, matched in one run: about as many scenes as 40 runs of one, in 12
@settings(max_examples=12, deadline=None)
@given(scenes=st.lists(st.tuples(BOXES, st.lists(BOXES, min_size=1, max_size=6)), min_size=1, max_size=6))
def test_box_distance_equals_shapely(tmp_path_factory, scenes):
    """box_distance_m is the exact distance between the two rotated rectangles (0 when they overlap)."""
    with example_dir(tmp_path_factory, "boxes") as tmp:
        db = make_db(tmp, [r for k, (ego, others) in enumerate(scenes) for r in scene_rows(f"d{k}", ego, others)])
        rel = relation_rows(db)
    assert rel["ego_id"].unique().to_list() == ["ego"]
    assert rel.height == sum(len(others) for _, others in scenes)  # every pair, within 22 m of each other
    for r in rel.iter_rows(named=True):
        ego, others = scenes[int(r["drive_id"][1:])]
        expected = box(*ego).distance(box(*others[int(r["actor_id"][1:])]))
        assert r["box_distance_m"] == pytest.approx(expected, abs=1e-6)


def test_gaps_headway_and_ttc_of_a_closing_follower(tmp_path):
    t = times(2.0)
    # follower 30 m behind (centres) at 14 m/s, ego at 10 m/s: bumper gap 25.5 m at t = 0, closing 4 m/s
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, 70 + 14 * t, Y1)])
    r0 = relation_rows(db).row(0, named=True)
    assert r0["dx_m"] == pytest.approx(-30.0)
    assert r0["lon_gap_m"] == pytest.approx(25.5)
    assert r0["lat_gap_m"] == 0.0
    assert r0["same_lane"] and r0["side"] == "left"  # dy = 0 counts as left
    assert r0["closing_speed_mps"] == pytest.approx(4.0, abs=1e-6)
    assert r0["time_headway_s"] == pytest.approx(25.5 / 14.0, abs=1e-6)
    assert r0["ttc_s"] == pytest.approx(25.5 / 4.0, abs=1e-6)
    assert r0["mttc_s"] == pytest.approx(25.5 / 4.0, abs=1e-4)  # no acceleration: MTTC = TTC


def test_ttc_is_null_when_not_closing_or_not_in_line(tmp_path):
    t = times(2.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                            actor("slower", t, 70 + 8 * t, Y1),      # behind and falling back
                            actor("beside", t, 70 + 14 * t, 8.0)])   # closing, but in another lane
    rel = relation_rows(db)
    assert rel.filter(pl.col("actor_id") == "slower")["ttc_s"].null_count() == rel.filter(
        pl.col("actor_id") == "slower").height
    beside = rel.filter(pl.col("actor_id") == "beside")
    assert beside["ttc_s"].null_count() == beside.height and (beside["lat_gap_m"] > 0).all()


def test_mttc_with_a_braking_leader(tmp_path):
    t = times(3.0)
    # ego follows a leader 20 m ahead (bumper gap 15.5 m) at equal speed; the leader brakes at 2 m/s^2
    lead_x = 120 + 15 * t - 0.5 * 2.0 * t**2
    db = make_db(tmp_path, [actor("ego", t, 100 + 15 * t, Y1, is_ego=True), actor("lead", t, lead_x, Y1)])
    rel = relation_rows(db).filter(pl.col("frame") == 10).row(0, named=True)
    # at t = 1: gap = 15.5 - 1 = 14.5 m, closing speed 2 m/s, closing accel 2 m/s^2:
    # 0.5*2*t^2 + 2*t - 14.5 = 0  ->  t = -1 + sqrt(1 + 14.5) = 2.937 s
    assert rel["lon_gap_m"] == pytest.approx(14.5, abs=1e-6)
    assert rel["closing_speed_mps"] == pytest.approx(2.0, abs=0.05)
    assert rel["mttc_s"] == pytest.approx(-1 + np.sqrt(1 + 14.5), abs=0.05)
    assert rel["ttc_s"] == pytest.approx(14.5 / 2.0, rel=0.03)


def test_pairs_beyond_the_relation_range_are_not_kept(tmp_path):
    t = times(1.0)
    # centres 200 m (the default range) and 201 m from the ego
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("far", t, 301 + 10 * t, Y1),
                            actor("near", t, 300 + 10 * t, Y1)])
    assert relation_rows(db)["actor_id"].unique().to_list() == ["near"]
