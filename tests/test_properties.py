"""Property tests of the interval SQL against brute-force Python oracles, on hypothesis-generated inputs.

The query files run as they are in DuckDB (queries/match/phase_islands.sql, queries/match/two_phases.sql,
queries/coverage/histogram.sql); each oracle walks frames or samples one by one. Derandomised, so CI sees the
same examples on every run. (tests/test_interval_oracle.py checks whole scenarios, duration limits included,
the same way through ingest and match.)
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import duckdb
import polars as pl
from hypothesis import given, settings
from hypothesis import strategies as st

from logiq_sql.match import _coverage_buckets
from logiq_sql.sql import materialise

DT = 0.1
PROFILE = settings(max_examples=60, deadline=None, derandomize=True)


def run(query: str, inputs: dict[str, pl.DataFrame], values: dict[str, object] | None = None) -> pl.DataFrame:
    con = duckdb.connect()
    for name, frame in inputs.items():
        con.register(f"_{name}", frame)
        con.execute(f"create temp table {name} as select * from _{name}")
    materialise(con, "out", query, values or {})
    return con.sql("select * from out").pl()


def runs(frames: list[int]) -> list[tuple[int, int]]:
    """Maximal runs of consecutive integers, walked one by one."""
    out: list[tuple[int, int]] = []
    for f in sorted(set(frames)):
        if out and f == out[-1][1] + 1:
            out[-1] = (out[-1][0], f)
        else:
            out.append((f, f))
    return out


# --- islands ----------------------------------------------------------------------------------------------------

# per actor, frame by frame: absent, or present with four phase flags; a frame may also have a second row
FRAME = st.one_of(st.none(), st.lists(st.lists(st.booleans(), min_size=4, max_size=4), min_size=1, max_size=2))
PAIR_FRAMES = st.fixed_dictionaries({"a": st.lists(FRAME, max_size=40), "b": st.lists(FRAME, max_size=40)})


@PROFILE
@given(pairs=PAIR_FRAMES)
def test_phase_islands_are_the_maximal_runs_of_each_phase(pairs):
    rows = [(actor, f, flags) for actor, frames in pairs.items() for f, present in enumerate(frames)
            if present is not None for flags in present]
    frame = pl.DataFrame(
        [{"drive_id": "d", "ego_id": "e", "actor_id": a, "frame": f, **{f"phase_{i + 1}": p[i] for i in range(4)}}
         for a, f, p in rows],
        schema={"drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String, "frame": pl.Int64,
                **{f"phase_{i}": pl.Boolean for i in range(1, 5)}})
    got = sorted(run("match/phase_islands.sql", {"phase_frames": frame}).select(
        "phase_index", "actor_id", "start_frame", "end_frame").iter_rows())
    expected = sorted(
        (i + 1, actor, a, b)
        for i in range(4) for actor in ("a", "b")
        for a, b in runs([f for x, f, p in rows if x == actor and p[i]])  # a frame holds if any of its rows does
    )
    assert got == expected


# --- sequential phases with duration limits --------------------------------------------------------------------------

def islands_of(flags: list[bool]) -> list[tuple[int, int]]:
    return runs([i for i, ok in enumerate(flags) if ok])


def oracle_two_phases(p1, p2, ego_frames, lim):
    """Matches of phase 1 directly followed by phase 2, trimmed to the maxima around the transition."""
    t = {f: round(f * DT, 6) for f in ego_frames}
    out = []
    for a1, b1 in p1:
        for a2, b2 in p2:
            if a2 != b1 + 1:
                continue
            first = [f for f in ego_frames if a1 <= f <= b1
                     and (lim["max1"] is None or t[f] >= b1 * DT - lim["max1"] - 1e-6)]
            last = [f for f in ego_frames if a2 <= f <= b2
                    and (lim["max2"] is None or t[f] <= a2 * DT + lim["max2"] + 1e-6)]
            if not first or not last:
                continue
            start, end = min(first), max(last)
            if b1 * DT - t[start] >= lim["min1"] - 1e-6 and t[end] - a2 * DT >= lim["min2"] - 1e-6:
                out.append((start, b1, a2, end))
    return sorted(out)


LIMIT = st.sampled_from([None, 0.0, 0.3, 1.0])


@PROFILE
@given(n=st.integers(2, 50).flatmap(lambda n: st.tuples(
           st.lists(st.booleans(), min_size=n, max_size=n), st.lists(st.booleans(), min_size=n, max_size=n),
           st.lists(st.booleans(), min_size=n, max_size=n))),
       min1=st.sampled_from([0.0, 0.2, 0.5]), min2=st.sampled_from([0.0, 0.2, 0.5]), max1=LIMIT, max2=LIMIT)
def test_two_phases_join_islands_that_touch_and_trim_them_to_the_limits(n, min1, min2, max1, max2):
    ok1, ok2, seen = n
    seen = [s or i % 5 == 0 for i, s in enumerate(seen)]  # the ego's own samples, some missing
    ego_frames = [i for i, s in enumerate(seen) if s]

    def phase(flags):
        rows = [{"drive_id": "d", "ego_id": "e", "actor_id": "a", "start_frame": a, "end_frame": b,
                 "start_s": round(a * DT, 6), "end_s": round(b * DT, 6)} for a, b in islands_of(flags)]
        return pl.DataFrame(rows, schema={"drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String,
                                          "start_frame": pl.Int64, "end_frame": pl.Int64, "start_s": pl.Float64,
                                          "end_s": pl.Float64})

    tracks = pl.DataFrame({"drive_id": "d", "actor_id": "e", "frame": ego_frames,
                           "t_s": [round(f * DT, 6) for f in ego_frames]},
                          schema={"drive_id": pl.String, "actor_id": pl.String, "frame": pl.Int64, "t_s": pl.Float64})
    lim = {"min1": min1, "min2": min2, "max1": max1, "max2": max2}
    got = run("match/two_phases.sql", {"phase_1": phase(ok1), "phase_2": phase(ok2), "tracks": tracks}, {
        "phase_1_min_duration_s": min1, "phase_2_min_duration_s": min2,
        "phase_1_max_duration_s": max1, "phase_2_max_duration_s": max2})
    got = sorted(got.select("p1_start_frame", "p1_end_frame", "p2_start_frame", "p2_end_frame").iter_rows())
    assert got == oracle_two_phases(islands_of(ok1), islands_of(ok2), ego_frames, lim)


# --- coverage buckets --------------------------------------------------------------------------------------------------

ITEMS = st.tuples(st.sampled_from([-10.0, 0.0, 2.5]), st.sampled_from([0.1, 0.5, 1.0, 2.5, 3.0]),
                  st.integers(1, 12))


@PROFILE
@given(spec=ITEMS, data=st.data())
def test_histogram_counts_every_sample_once_in_its_half_open_bucket(spec, data):
    lo, every, n = spec
    hi = lo + n * every
    item = SimpleNamespace(name="x", values=None, lo=lo, hi=hi, every=every)
    enum = SimpleNamespace(name="kind", values=("car", "bike"), lo=None, hi=None, every=None)
    buckets = _coverage_buckets(SimpleNamespace(name="s", coverage=[item, enum]))
    edges = [b for b in buckets["lo"].drop_nulls().to_list()] + [hi]
    value = st.one_of(st.sampled_from(edges), st.floats(lo - 2 * every, hi + 2 * every), st.none(),
                      st.sampled_from([math.nextafter(e, -math.inf) for e in edges]))
    nums = data.draw(st.lists(value, max_size=30))
    texts = data.draw(st.lists(st.sampled_from(["car", "bike", "boat", None]), max_size=10))
    samples = pl.DataFrame(
        [{"scenario": "s", "match_id": f"m{i}", "item": "x", "value_num": v, "value_text": None}
         for i, v in enumerate(nums)]
        + [{"scenario": "s", "match_id": f"k{i}", "item": "kind", "value_num": None, "value_text": v}
           for i, v in enumerate(texts)],
        schema={"scenario": pl.String, "match_id": pl.String, "item": pl.String, "value_num": pl.Float64,
                "value_text": pl.String})
    got = {(r["item"], r["bucket"]): r["hits"]
           for r in run("coverage/histogram.sql", {"coverage_samples": samples, "coverage_buckets": buckets}
                        ).iter_rows(named=True)}

    expected = {("x", b["bucket"]): 0 for b in buckets.iter_rows(named=True) if b["item"] == "x"}
    expected.update({("kind", "car"): 0, ("kind", "bike"): 0})
    numeric = [b for b in buckets.iter_rows(named=True) if b["item"] == "x"]
    for v in nums:
        hit = [b["bucket"] for b in numeric if v is not None and b["lo"] <= v < b["hi"]]
        assert len(hit) <= 1  # buckets do not overlap
        key = ("x", hit[0] if hit else ("missing" if v is None else "out_of_range"))
        expected[key] = expected.get(key, 0) + 1
    for v in texts:
        key = ("kind", v if v in ("car", "bike") else ("missing" if v is None else "out_of_range"))
        expected[key] = expected.get(key, 0) + 1
    assert got == expected
    assert sum(got.values()) == len(nums) + len(texts)  # no sample lost, none counted twice


# --- a single phase with a maximum duration ------------------------------------------------------------------------

CYCLIST_FRAME = st.one_of(st.none(), st.tuples(
    st.sampled_from(["cyclist", "cyclist", "cyclist", "person"]),
    st.sampled_from([0.0, 0.5, 2.0, 4.999, 5.0, 5.001, 9.0]),  # box distance, on and around the 0-5 m limits
    st.sampled_from([8.0, 8.0, 1.4, 5 / 3.6, 1.3889, 1.3, 0.0]),  # ego speed, around 5 kph = 1.38889 m/s
))


# runs of 1 to 15 frames in one state, so that episodes last long enough to be cut
CYCLIST_FRAMES = st.lists(st.tuples(st.integers(1, 15), CYCLIST_FRAME), max_size=8).map(
    lambda segments: [state for n, state in segments for _ in range(n)])


@PROFILE
@given(frames=CYCLIST_FRAMES, dt=st.sampled_from([0.1, 0.05, 0.04]),
       max_s=st.sampled_from([0.0, 0.1, 0.3, 1.0, 2.55]))
def test_cyclist_phase_cuts_episodes_into_pieces_of_at_most_the_maximum(frames, dt, max_s):
    present = [(f, x) for f, x in enumerate(frames) if x is not None]
    relations = pl.DataFrame(
        [{"drive_id": "d", "ego_id": "e", "actor_id": "c", "frame": f, "t_s": f * dt, "actor_kind": kind,
          "box_distance_m": dist} for f, (kind, dist, _) in present],
        schema={"drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String, "frame": pl.Int64,
                "t_s": pl.Float64, "actor_kind": pl.String, "box_distance_m": pl.Float64})
    tracks = pl.DataFrame([{"drive_id": "d", "actor_id": "e", "frame": f, "speed_mps": v} for f, (_, _, v) in present],
                          schema={"drive_id": pl.String, "actor_id": pl.String, "frame": pl.Int64,
                                  "speed_mps": pl.Float64})
    drives = pl.DataFrame({"drive_id": ["d"], "dt_s": [dt]})
    got = run("phases/cyclist_close_to_moving_sut.sql",
              {"relations": relations, "tracks": tracks, "drive_inputs": drives},
              {"sut_minimal_speed_mps": 5 / 3.6, "min_distance_from_cyclist_m": 0.0,
               "max_distance_from_cyclist_m": 5.0, "max_phase_duration_s": max_s})
    got = sorted(got.select("start_frame", "end_frame").iter_rows())

    holds = [f for f, (kind, dist, v) in present if kind == "cyclist" and 0.0 <= dist <= 5.0 and v >= 5 / 3.6]
    span = math.floor(max_s / dt + 1e-9) + 1  # frames a piece may span
    expected = sorted((a, min(a + span - 1, b)) for start, b in runs(holds) for a in range(start, b + 1, span))
    assert got == expected
    assert all((b - a) * dt <= max_s + 1e-9 for a, b in got)  # no piece lasts longer than the maximum
