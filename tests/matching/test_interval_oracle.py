"""The phase SQL against a brute-force Python oracle on random per-frame conditions.

The follower sits either at a headway inside [0 s, 5 s] or far outside it, frame by frame, and some of its
frames are missing; the oracle walks the frames one by one, bridging interruptions of at most max_gap, and drops
a bridged run that held at fewer than half of its frames.
"""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from logiq_sql.matching.explain import explain
from logiq_sql.matching.match import match
from tests.helpers import Y1, example_dir, intervals, make_db

DT = 0.1


def oracle_islands(frames_ok: list[bool], min_s: float | None, max_s: float | None,
                   max_gap_s: float = 0.0) -> list[tuple[float, float]]:
    gap = math.floor(max_gap_s / DT + 1e-9)  # frames of interruption bridged
    runs: list[list[int]] = []
    for i, ok in enumerate(frames_ok):
        if not ok:
            continue
        if runs and i - runs[-1][1] - 1 <= gap:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    out = []
    for start, end in runs:
        if 2 * sum(frames_ok[start:end + 1]) < end - start + 1:  # held at fewer than half its frames: jitter
            continue
        if (end - start) * DT < max_gap_s - 1e-6:  # shorter than max_gap: jitter, not an episode
            continue
        if max_s is not None:  # consecutive pieces spanning at most max_s
            span = math.floor(max_s / DT + 1e-9) + 1
            for a in range(start, end + 1, span):
                out.append((a, min(a + span - 1, end)))
        elif (end - start) * DT >= min_s - 1e-9:
            out.append((start, end))
    return [(round(a * DT, 3), round(b * DT, 3)) for a, b in out]


def drive(ok: list[bool], present: list[bool], kind: str, near: float, far: float, lateral: bool) -> pl.DataFrame:
    n = len(ok)
    t = np.round(np.arange(n) * DT, 6)
    ego = pl.DataFrame({"drive_id": "d1", "actor_id": "ego", "kind": "vehicle", "is_ego": True, "t_s": t,
                        "x_m": 100 + 10 * t, "y_m": Y1, "heading_rad": 0.0, "speed_mps": 10.0,
                        "length_m": 4.5, "width_m": 1.8})
    offset = np.where(ok, near, far)
    other = pl.DataFrame({
        "drive_id": "d1", "actor_id": "a", "kind": kind, "is_ego": False, "t_s": t,
        "x_m": 100 + 10 * t - (0.0 if lateral else offset), "y_m": Y1 + (offset if lateral else 0.0),
        "heading_rad": 0.0, "speed_mps": 10.0, "length_m": 4.5, "width_m": 1.8,
    }).filter(pl.Series(present))
    return [ego, other]


FRAMES = st.integers(min_value=2, max_value=60).flatmap(
    lambda n: st.tuples(st.lists(st.booleans(), min_size=n, max_size=n),
                        st.lists(st.booleans(), min_size=n, max_size=n).map(
                            lambda xs: [x or (i % 7 != 3) for i, x in enumerate(xs)])))


def matched_vs_oracle(tmp, frames, scenario, tracks_args, override, min_s, max_s, max_gap_s):
    """(intervals the SQL found, intervals the oracle expects) for one random case."""
    ok, present = frames
    db = make_db(tmp, drive(ok, present, *tracks_args))
    got = intervals(match(db, scenarios=[scenario], ego="recorded",
                          overrides={**override, "max_gap": f"{max_gap_s}s"}).matches, scenario)
    expected = oracle_islands([o and p for o, p in zip(ok, present, strict=True)], min_s, max_s, max_gap_s)
    return [(a, b) for _, _, a, b in got], expected


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=FRAMES, min_s=st.sampled_from([0.0, 0.5, 1.0, 2.0]), max_gap_s=st.sampled_from([0.0, 0.2, 0.5]))
def test_follower_islands_match_the_oracle(tmp_path_factory, frames, min_s, max_gap_s):
    # centre offset 20 m -> gap 15.5 m -> 1.55 s; 90 m -> gap 85.5 m -> 8.55 s (outside [0, 5] s)
    with example_dir(tmp_path_factory, "f") as tmp:
        got, expected = matched_vs_oracle(tmp, frames, "follower_vehicle",
                                          ("vehicle", 20.0, 90.0, False),
                                          {"min_scenario_duration": f"{min_s}s"}, min_s, None, max_gap_s)
    assert got == expected


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=FRAMES, max_s=st.sampled_from([0.3, 1.0, 2.55]), max_gap_s=st.sampled_from([0.0, 0.3]))
def test_cyclist_pieces_match_the_oracle(tmp_path_factory, frames, max_s, max_gap_s):
    # lateral centre offset 4 m -> box gap 2.2 m (inside [0, 5] m); 12 m -> 10.2 m (outside)
    with example_dir(tmp_path_factory, "c") as tmp:
        got, expected = matched_vs_oracle(tmp, frames, "cyclist_close_to_moving_sut",
                                          ("cyclist", 4.0, 12.0, True),
                                          {"max_phase_duration": f"{max_s}s"}, None, max_s, max_gap_s)
    assert got == expected


@pytest.mark.parametrize(("held_every", "matched"), [((0,), False), ((0, 1), True)])
def test_a_run_held_at_fewer_than_half_of_its_frames_is_jitter(tmp_path, held_every, matched):
    """A cyclist whose distance the noise carries under 5 m at one frame in three (the gaps of two frames are
    bridged by max_gap = 0.5 s) gives no match, and explain says the run was dropped as jitter; at two frames in
    three the run holds at most of its frames and is one match (docs/semantics.md, "Decision (gaps and jitter)")."""
    ok = [i % 3 in held_every for i in range(40)]
    db = make_db(tmp_path, drive(ok, [True] * 40, "cyclist", 4.0, 7.5, True))  # box gap 2.2 m, or 5.7 m
    got = intervals(match(db, scenarios=["cyclist_close_to_moving_sut"], ego="recorded",
                          overrides={"max_phase_duration": "10s"}).matches, "cyclist_close_to_moving_sut")
    text = explain(db, "cyclist_close_to_moving_sut", "d1", "ego", actor="a").text()
    if matched:
        assert [(a, b) for _, _, a, b in got] == [(0.0, 3.9)]
        assert "bridged" in text and "jitter" not in text
    else:
        assert got == []
        assert "could not begin at t = 0.00 s (frame 0):\n    all its conditions hold at this frame, but only in " \
               "a run dropped as jitter (below)" in text
        assert "cyclist_close_to_moving_sut frames 0-39 (0.0 s to 3.9 s): 26 frame(s) missing or not holding, " \
               "more than it held: dropped as jitter" in text
