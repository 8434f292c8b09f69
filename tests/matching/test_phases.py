"""Each phase on small hand-made tracks with the intervals worked out by hand."""

from __future__ import annotations

import numpy as np

from logiq_sql.matching.match import match
from tests.helpers import LANE_W, Y1, Y2, actor, intervals, lane, make_db, times

FOLLOWER = "follower_vehicle"
CYCLIST = "cyclist_close_to_moving_sut"


def run(db, scenario, **kw):
    return intervals(match(db, scenarios=[scenario], **kw).matches, scenario)


# --- follower_vehicle -------------------------------------------------------------------------------------

def test_follower_at_steady_headway_matches_the_whole_drive(tmp_path):
    t = times(6.0)
    # centre gap 20 m, boxes 4.5 m long: bumper gap 15.5 m at 10 m/s -> headway 1.55 s
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, 80 + 10 * t, Y1)])
    assert run(db, FOLLOWER) == [("ego", "f", 0.0, 6.0)]


def test_follower_headway_limits_are_honoured(tmp_path):
    t = times(6.0)
    # bumper gap 75.5 m at 10 m/s -> 7.55 s: beyond the default 5 s, inside 8 s
    db = make_db(tmp_path, [actor("ego", t, 200 + 10 * t, Y1, is_ego=True), actor("f", t, 120 + 10 * t, Y1)])
    assert run(db, FOLLOWER) == []
    assert run(db, FOLLOWER, overrides={"max_distance_from_sut_in_time_units": "8sec"}) == [("ego", "f", 0.0, 6.0)]
    assert run(db, FOLLOWER, overrides={"max_distance_from_sut_in_time_units": "8sec",
                                        "min_distance_from_sut_in_time_units": "7.6s"}) == []


def test_follower_must_be_behind_and_in_the_same_lane(tmp_path):
    t = times(6.0)
    db = make_db(tmp_path, [
        actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
        actor("ahead", t, 120 + 10 * t, Y1),        # in front: a lead vehicle, not a follower
        actor("beside", t, 80 + 10 * t, Y2),        # behind but in the left lane
    ])
    assert run(db, FOLLOWER) == []


def test_an_actor_alongside_or_overlapping_the_ego_is_not_following(tmp_path):
    t = times(3.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                            actor("overlap", t, 97 + 10 * t, Y1),        # its front is 1.5 m into the ego's rear
                            actor("touching", t, 95.4 + 10 * t, Y1)])    # 0.1 m gap: following
    assert [m[1] for m in run(db, FOLLOWER)] == ["touching"]


def test_follower_shorter_than_min_scenario_duration_is_not_a_match(tmp_path):
    t = times(3.0)
    ego = actor("ego", t, 100 + 10 * t, Y1, is_ego=True)
    short = make_db(tmp_path / "short", [ego, actor("f", t[:10], 80 + 10 * t[:10], Y1)])   # 0.0 .. 0.9 s
    exact = make_db(tmp_path / "exact", [ego, actor("g", t[:11], 80 + 10 * t[:11], Y1)])   # 0.0 .. 1.0 s
    assert run(short, FOLLOWER) == []
    assert run(exact, FOLLOWER) == [("ego", "g", 0.0, 1.0)]
    assert run(short, FOLLOWER, overrides={"min_scenario_duration": "0.9s"}) == [("ego", "f", 0.0, 0.9)]


def test_only_the_nearest_road_user_behind_follows_the_ego(tmp_path):
    t = times(6.0)
    # "near" is right behind the ego until it leaves the lane after 3 s; then "far" follows the ego
    near_y = np.where(t <= 3.0, Y1, Y2)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                            actor("near", t, 85 + 10 * t, near_y), actor("far", t, 65 + 10 * t, Y1)])
    assert run(db, FOLLOWER) == [("ego", "far", 3.1, 6.0), ("ego", "near", 0.0, 3.0)]


def test_follower_kinds_filter(tmp_path):
    t = times(3.0)
    ego = actor("ego", t, 100 + 10 * t, Y1, is_ego=True)
    truck = make_db(tmp_path / "truck", [ego, actor("truck", t, 80 + 10 * t, Y1, kind="truck", length=10.0)])
    bike = make_db(tmp_path / "bike", [ego, actor("bike", t, 85 + 10 * t, Y1, kind="cyclist", length=1.8, width=0.6)])
    assert [m[1] for m in run(truck, FOLLOWER)] == ["truck"]          # unset kinds: vehicle kinds only
    assert run(truck, FOLLOWER, overrides={"kinds": "vehicle"}) == []
    assert run(bike, FOLLOWER) == []
    assert [m[1] for m in run(bike, FOLLOWER, overrides={"kinds": "cyclist,truck"})] == ["bike"]


def test_ego_lane_change_ends_the_phase(tmp_path):
    t = times(8.0)
    # the ego moves from the right lane to the left lane between t=3 and t=5 (1.75 m/s sideways)
    y = np.clip(Y1 + (t - 3.0) * (LANE_W / 2.0), Y1, Y2)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, y, is_ego=True), actor("f", t, 80 + 10 * t, Y1)])
    (m,) = run(db, FOLLOWER)
    # the follower stays in L1; the ego's centre crosses into L2 at t = 4.0 (y = 3.5), and the lane change is
    # counted once it is more than the 1 m tolerance away from L1 (y > 4.5, from t = 4.6)
    assert m[2] == 0.0 and 3.9 <= m[3] <= 4.6


def test_follower_on_the_previous_road_segment_counts_as_same_lane(tmp_path):
    t = times(5.0)
    # the road is split in two segments at x = 150: A then B; the ego is on B, the follower on A until t = 3
    lanes = [lane("A", 0.0, 0.0, 150.0), lane("B", 0.0, 150.0, 2000.0)]
    ego = actor("ego", t, 160 + 10 * t, Y1, is_ego=True)
    fol = actor("f", t, 120 + 10 * t, Y1)
    linked = make_db(tmp_path / "linked", [ego, fol], lanes,
                     successors=[dict(map_id="road", lane_id="A", successor_id="B", turn=None)])
    assert run(linked, FOLLOWER) == [("ego", "f", 0.0, 5.0)]
    # without the map link the ego never drove on A in this drive, so the follower is on the ego's road only
    # once it is on B: from t = 3.0 (it sits on the boundary: its best lane is A by id, but its centre is inside
    # the ego's lane B as well, and a centre inside both of two lanes is in either)
    unlinked = make_db(tmp_path / "unlinked", [ego, fol], lanes)
    assert run(unlinked, FOLLOWER) == [("ego", "f", 3.0, 5.0)]


def test_same_road_limit_uses_the_lanes_the_ego_drove_in(tmp_path):
    t = times(6.0)
    lanes = [lane("A", 0.0, 0.0, 150.0), lane("B", 0.0, 150.0, 2000.0)]
    # the ego crosses from A to B at t = 2 s (x = 150); the follower, 30 m behind, stays on A until t = 5 s
    ego = actor("ego", t, 130 + 10 * t, Y1, is_ego=True)
    fol = actor("f", t, 100 + 10 * t, Y1)
    db = make_db(tmp_path, [ego, fol], lanes)
    assert run(db, FOLLOWER) == [("ego", "f", 0.0, 6.0)]
    # with a 1 s limit the follower, still on A, is no longer on the ego's road from about t = 3 s on
    (m,) = run(db, FOLLOWER, overrides={"same_road_limit": "1sec"})
    assert m[2] == 0.0 and 2.9 <= m[3] <= 3.3


def test_a_car_on_another_approach_to_the_ego_s_lane_is_not_its_follower(tmp_path):
    t = times(6.0)
    # two approaches, A and B (20 m to its left), both lead into X at x = 150; the ego drives A then X (from
    # t = 2 s), the actor stays on B, 30 m behind: B is a predecessor of X, but not a lane the ego drove
    lanes = [lane("A", 0.0, 0.0, 150.0), lane("B", 20.0, 0.0, 150.0), lane("X", 0.0, 150.0, 2000.0)]
    links = [dict(map_id="road", lane_id=a, successor_id="X", turn=None) for a in ("A", "B")]
    ego = actor("ego", t, 130 + 10 * t, Y1, is_ego=True)
    other = actor("b", t, 100 + 10 * t, 20.0 + Y1)
    assert run(make_db(tmp_path, [ego, other], lanes, successors=links), FOLLOWER) == []


def test_a_road_user_turning_off_the_ego_s_road_still_stands_between(tmp_path):
    t = times(10.0)
    # A leads into X (straight on) and R (a right turn, south from x = 150). The ego drives A then X at 10 m/s,
    # 15 m ahead of a turner (A then R) and 30 m ahead of a car behind it (A). Until the turner's centre leaves A
    # (t = 6.7) the turner follows the ego. On R it is no longer on the ego's road, but still between the two:
    # its follow gap (lon + lat) is less than the car's 25.5 m until t = 7.5 (20.1 + 5.1 m; at 7.6, 21.1 + 6.1),
    # so the car behind follows the ego from t = 7.6, not from t = 6.8 as when the turner counted for nothing
    south = dict(lane("R", 0.0), lane_id="R",
                 polygon_wkt="POLYGON ((150 0, 153.5 0, 153.5 -2000, 150 -2000, 150 0))",
                 centerline_wkt="LINESTRING (151.75 0, 151.75 -2000)")
    lanes = [lane("A", 0.0, 0.0, 150.0), lane("X", 0.0, 150.0, 2000.0), south]
    links = [dict(map_id="road", lane_id="A", successor_id=s, turn=None) for s in ("X", "R")]
    ego = actor("ego", t, 100 + 10 * t, Y1, is_ego=True)
    along = 85 + 10 * t
    turner = actor("t", t, np.minimum(along, 151.75), Y1 - np.maximum(along - 151.75, 0.0))
    behind = actor("f", t, 70 + 10 * t, Y1)
    db = make_db(tmp_path, [ego, turner, behind], lanes, successors=links)
    assert run(db, FOLLOWER, ego="ego") == [("ego", "f", 7.6, 10.0), ("ego", "t", 0.0, 6.7)]


def test_an_actor_bound_for_another_exit_stops_following_once_the_ego_is_past_the_fork(tmp_path):
    t = times(8.0)
    # A forks into J (straight on, 10 m of junction) and R (a right turn, south from x = 146.5-150); J leads into
    # X. The ego drives A, J, X at 10 m/s from x = 130: its centre is in X from t = 3.1. The turner, 20 m behind
    # (bumper gap 15.5 m, 1.55 s), turns south at x = 148.25 (t = 3.825) and is on A until t = 4.0, then on R.
    # While the ego is on A or on J (A's successor) the turner follows it; once the ego is on X, past the fork, a
    # car on A bound for R does not: it follows from 0.0 to 3.0 (with the old rule until 3.9, the turn's growing
    # gap ending it). A car going straight on follows the ego the whole time
    south = dict(lane("R", 0.0), lane_id="R",
                 polygon_wkt="POLYGON ((146.5 0, 150 0, 150 -2000, 146.5 -2000, 146.5 0))",
                 centerline_wkt="LINESTRING (148.25 0, 148.25 -2000)")
    lanes = [lane("A", 0.0, 0.0, 150.0), lane("J", 0.0, 150.0, 160.0), lane("X", 0.0, 160.0, 2000.0), south]
    links = [dict(map_id="road", lane_id=a, successor_id=b, turn=None) for a, b in (("A", "J"), ("A", "R"), ("J", "X"))]
    ego = actor("ego", t, 130 + 10 * t, Y1, is_ego=True)
    along = 110 + 10 * t
    turner = actor("t", t, np.minimum(along, 148.25), Y1 - np.maximum(along - 148.25, 0.0))
    straight = actor("s", t, along, Y1)
    assert run(make_db(tmp_path / "turner", [ego, turner], lanes, successors=links), FOLLOWER) == [
        ("ego", "t", 0.0, 3.0)]
    assert run(make_db(tmp_path / "straight", [ego, straight], lanes, successors=links), FOLLOWER) == [
        ("ego", "s", 0.0, 8.0)]


def test_the_gap_to_a_follower_is_not_shrunk_by_the_ego_s_turn(tmp_path):
    t = times(6.0)
    # the ego drives east on A, turns north at x = 151.75 (t = 2.175 s) onto N; the actor stays on A, 100 m
    # behind (a 9.5 s headway). After the turn the actor is a few metres behind the ego along its new heading,
    # but 100 m away: the gap is the distance between the boxes, and no follower
    north = dict(lane("N", 0.0), lane_id="N",
                 polygon_wkt="POLYGON ((150 0, 153.5 0, 153.5 2000, 150 2000, 150 0))",
                 centerline_wkt="LINESTRING (151.75 0, 151.75 2000)")
    lanes = [lane("A", 0.0, 0.0, 150.0), north]
    along = 130 + 10 * t
    ego = actor("ego", t, np.minimum(along, 151.75), Y1 + np.maximum(along - 151.75, 0.0), is_ego=True)
    behind = actor("f", t, 30 + 10 * t, Y1)
    assert run(make_db(tmp_path, [ego, behind], lanes), FOLLOWER) == []


def test_the_gap_to_a_follower_behind_a_turn_runs_round_the_corner(tmp_path):
    t = times(8.0)
    # as above, the actor now 60 m behind at 9 m/s. After the ego's turn the road from the actor to the ego runs
    # west-east then south-north: at t = 5 s about 32 m + 28 m, a 6 s headway (no follower), while the straight
    # line between the boxes (about 38 m, 4.2 s) would make it one from about 4 s on
    north = dict(lane("N", 0.0), lane_id="N",
                 polygon_wkt="POLYGON ((150 0, 153.5 0, 153.5 2000, 150 2000, 150 0))",
                 centerline_wkt="LINESTRING (151.75 0, 151.75 2000)")
    along = 130 + 10 * t
    ego = actor("ego", t, np.minimum(along, 151.75), Y1 + np.maximum(along - 151.75, 0.0), is_ego=True)
    behind = actor("f", t, 70 + 9 * t, Y1)
    db = make_db(tmp_path, [ego, behind], [lane("A", 0.0, 0.0, 150.0), north])
    assert run(db, FOLLOWER) == []
    # with a 7 s maximum headway it is one: what rejects it is the headway along that path
    assert run(db, FOLLOWER, overrides={"max_distance_from_sut_in_time_units": "7sec"}) == [("ego", "f", 0.0, 8.0)]



def test_a_car_following_a_long_ego_round_a_sharp_turn_still_follows_it(tmp_path):
    # A leads through the junction lane J into X, a 120-degree right turn of radius 6 m at x = 150. A 12 m ego
    # (a bus) drives it at 4 m/s, a car 14 m behind (centre to centre: a 5.7 m bumper gap, 1.4 s). Through the
    # turn the bus's rear swings across A, so for about 1.8 s the car, still on A, is off to the side of the
    # bus's rear on its new heading (lon_gap_m = 0) though it is behind it along the road it drove; SUMO's
    # leaderID says it follows all along (issue 36, junction_skew30_cycle120). Before, the match broke in two
    # (0.0-6.9 s and 8.7-12.0 s)
    t = times(12.0)
    radius, turn = 6.0, np.radians(120.0)

    def path(s):
        bend = np.clip((s - 150) / radius, 0, turn)
        beyond = np.maximum(s - 150 - turn * radius, 0)
        x = np.where(s < 150, s, 150 + radius * np.sin(bend)) + beyond * np.cos(turn)
        y = np.where(s < 150, Y1, Y1 - radius + radius * np.cos(bend)) - beyond * np.sin(turn)
        return x, y

    end_x, end_y = path(np.array(150 + turn * radius))
    far_x, far_y = path(np.array(1150 + turn * radius))
    side_x, side_y = LANE_W / 2 * np.sin(turn), LANE_W / 2 * np.cos(turn)  # half a lane across the exit

    def ring(points):
        return "POLYGON ((" + ", ".join(f"{x:.3f} {y:.3f}" for x, y in [*points, points[0]]) + "))"

    lanes = [lane("A", 0.0, 0.0, 150.0),
             dict(lane("J", 0.0), lane_id="J", centerline_wkt=f"LINESTRING (150 {Y1}, {end_x:.3f} {end_y:.3f})",
                  polygon_wkt=ring([(150, LANE_W), (150, Y1 - radius - 3), (end_x + 3, Y1 - radius - 3),
                                    (end_x + 3, LANE_W)])),
             dict(lane("X", 0.0), lane_id="X",
                  centerline_wkt=f"LINESTRING ({end_x:.3f} {end_y:.3f}, {far_x:.3f} {far_y:.3f})",
                  polygon_wkt=ring([(end_x - side_x, end_y - side_y), (far_x - side_x, far_y - side_y),
                                    (far_x + side_x, far_y + side_y), (end_x + side_x, end_y + side_y)]))]
    links = [dict(map_id="road", lane_id=a, successor_id=b, turn=None) for a, b in (("A", "J"), ("J", "X"))]
    bus = actor("ego", t, *path(130 + 4 * t), is_ego=True, length=12.0)
    car = actor("f", t, *path(116 + 4 * t))
    assert run(make_db(tmp_path, [bus, car], lanes, successors=links), FOLLOWER) == [("ego", "f", 0.0, 12.0)]

# --- cyclist_close_to_moving_sut --------------------------------------------------------------------------

def cyclist_at(t, x, y):
    return actor("c", t, x, y, kind="cyclist", length=1.8, width=0.6)


def test_cyclist_distance_band_and_ego_speed(tmp_path):
    t = times(4.0)
    # ego box y in [0.85, 2.65]; cyclist box y from 3.0+...: lateral box gap = y_c - 0.3 - 2.65
    ego = actor("ego", t, 100 + 10 * t, Y1, is_ego=True)
    near = actor("near", t, 100 + 10 * t, 6.95, kind="cyclist", length=1.8, width=0.6)   # gap 4.0 m
    far = actor("far", t, 100 + 10 * t, 8.95, kind="cyclist", length=1.8, width=0.6)    # gap 6.0 m
    car = actor("car", t, 100 + 10 * t, 6.95)                                            # not a cyclist
    db = make_db(tmp_path, [ego, near, far, car])
    assert run(db, CYCLIST) == [("ego", "near", 0.0, 4.0)]
    assert run(db, CYCLIST, overrides={"max_distance_from_cyclist": "3.9m"}) == []
    assert [m[1] for m in run(db, CYCLIST, overrides={"max_distance_from_cyclist": "6m"})] == ["far", "near"]
    assert run(db, CYCLIST, overrides={"min_distance_from_cyclist": "4.5m",
                                       "max_distance_from_cyclist": "6m"}) == [("ego", "far", 0.0, 4.0)]


def test_cyclist_needs_a_moving_ego(tmp_path):
    t = times(4.0)
    # ego speeds up from 0 at 1 m/s^2: 5 kph (1.389 m/s) reached at t ~= 1.39 s
    x = 100 + 0.5 * t**2
    ego = actor("ego", t, x, Y1, is_ego=True)
    cyc = actor("c", t, x + 3.0, 5.0, kind="cyclist", length=1.8, width=0.6)
    db = make_db(tmp_path, [ego, cyc])
    (m,) = run(db, CYCLIST)
    assert 1.3 <= m[2] <= 1.5 and m[3] == 4.0
    # 20 kph = 5.56 m/s is never reached: the ego tops out at 4 m/s
    assert run(db, CYCLIST, overrides={"sut_minimal_speed": "20kph"}) == []


def test_long_cyclist_episode_is_cut_into_pieces_of_max_phase_duration(tmp_path):
    t = times(12.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                            actor("c", t, 100 + 10 * t, 5.0, kind="cyclist", length=1.8, width=0.6)])
    assert run(db, CYCLIST) == [("ego", "c", 0.0, 5.0), ("ego", "c", 5.1, 10.1), ("ego", "c", 10.2, 12.0)]
    assert run(db, CYCLIST, overrides={"max_phase_duration": "20s"}) == [("ego", "c", 0.0, 12.0)]


def test_a_gap_of_at_most_max_gap_is_bridged_a_longer_one_splits_the_phase(tmp_path):
    t = times(6.0)
    keep = (t < 2.0) | (t > 2.25)  # frames 20, 21, 22 (0.3 s) are missing for the follower: a missed detection
    db = make_db(tmp_path / "a", [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                                  actor("f", t[keep], 80 + 10 * t[keep], Y1)])
    assert run(db, FOLLOWER) == [("ego", "f", 0.0, 6.0)]  # max_gap 0.5 s bridges it
    assert run(db, FOLLOWER, overrides={"max_gap": "0s"}) == [("ego", "f", 0.0, 1.9), ("ego", "f", 2.3, 6.0)]
    assert run(db, FOLLOWER, overrides={"max_gap": "0.2s"}) == [("ego", "f", 0.0, 1.9), ("ego", "f", 2.3, 6.0)]
    assert run(db, FOLLOWER, overrides={"max_gap": "0.3s"}) == [("ego", "f", 0.0, 6.0)]
    longer = (t < 2.0) | (t > 2.55)  # 0.6 s missing: the follower was lost, two episodes
    db = make_db(tmp_path / "b", [actor("ego", t, 100 + 10 * t, Y1, is_ego=True),
                                  actor("f", t[longer], 80 + 10 * t[longer], Y1)])
    assert run(db, FOLLOWER) == [("ego", "f", 0.0, 1.9), ("ego", "f", 2.6, 6.0)]


def test_a_condition_flickering_false_for_at_most_max_gap_is_bridged(tmp_path):
    """A measurement glitch: the follower's position jumps 41 m back on frames 30 and 31. Its speed, derived
    from positions, is negative on frames 29 and 30, so its headway is undefined there and the phase's condition
    is false for 0.2 s; max_gap bridges it, max_gap = 0 splits the phase there."""
    t = times(6.0)
    x = 80 + 10 * t
    x[30:32] -= 41.0
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, x, Y1)])
    assert run(db, FOLLOWER) == [("ego", "f", 0.0, 6.0)]
    assert run(db, FOLLOWER, overrides={"max_gap": "0s"}) == [("ego", "f", 0.0, 2.8), ("ego", "f", 3.1, 6.0)]
