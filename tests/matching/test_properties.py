"""Property tests of the interval SQL against brute-force Python oracles, on hypothesis-generated inputs.

The query files run as they are in DuckDB (queries/match/phase_runs.sql, queries/match/chain.sql with
queries/match/sequential.sql, queries/coverage/histogram.sql); each oracle walks frames or samples one by one.
Derandomised, so CI sees the same examples on every run. (tests/matching/test_interval_oracle.py checks whole scenarios,
duration limits included, the same way through ingest and match.)
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import duckdb
import polars as pl
from hypothesis import given, settings
from hypothesis import strategies as st

from logiq_sql.core.sql import materialise, per_phase
from logiq_sql.matching.runner import coverage_buckets

DT = 0.1
PROFILE = settings(max_examples=60, deadline=None, derandomize=True)
PHASE_SCHEMA = {"drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String, "drive_key": pl.Int64,
                "ego_key": pl.Int64, "actor_key": pl.Int64, "frame": pl.Int64, "t_s": pl.Float64, "segment": pl.Int64,
                "holds": pl.Boolean}


def run(query: str, inputs: dict[str, pl.DataFrame], values: dict[str, object] | None = None) -> pl.DataFrame:
    con = duckdb.connect()
    for name, frame in inputs.items():
        con.register(f"_{name}", frame)
        con.execute(f"create temp table {name} as select * from _{name}")
    materialise(con, "out", query, values or {})
    return con.sql("select * from out").pl()


def bridged_runs(frames: list[int], gap: int = 0) -> list[tuple[int, int]]:
    """Runs of frames, walked one by one: a new run when more than ``gap`` frames are missing in between."""
    out: list[tuple[int, int]] = []
    for f in sorted(set(frames)):
        if out and f - out[-1][1] - 1 <= gap:
            out[-1] = (out[-1][0], f)
        else:
            out.append((f, f))
    return out


DRIVES = pl.DataFrame({"drive_id": ["d"], "drive_key": [1], "dt_s": [DT]})
# the integer keys of the drive's actors (tracks.actor_key): the ego e, the actors a, b and the cyclist c
KEYS = {"e": 1, "a": 2, "b": 3, "c": 4}
# a track row of each actor but the ego (whose rows each test writes): where match/sequential.sql reads their ids
OTHER_ACTORS = pl.DataFrame({"drive_id": "d", "actor_id": [a for a in KEYS if a != "e"], "drive_key": 1,
                             "actor_key": [k for a, k in KEYS.items() if a != "e"], "frame": 0, "t_s": 0.0})


# --- runs -----------------------------------------------------------------------------------------------------------

# per actor, frame by frame: absent, or present with four phase flags and a segment; a frame may have a second row
FRAME = st.one_of(st.none(), st.lists(st.tuples(st.lists(st.booleans(), min_size=4, max_size=4),
                                                st.integers(0, 1)), min_size=1, max_size=2))
PAIR_FRAMES = st.fixed_dictionaries({"a": st.lists(FRAME, max_size=40), "b": st.lists(FRAME, max_size=40)})


@PROFILE
@given(pairs=PAIR_FRAMES, max_gap_s=st.sampled_from([0.0, 0.1, 0.3]))
def test_phase_runs_are_the_bridged_runs_of_each_phase_and_segment(pairs, max_gap_s):
    rows = [(actor, f, flags, seg) for actor, frames in pairs.items() for f, present in enumerate(frames)
            if present is not None for flags, seg in present]
    phases = {f"phase_{i + 1}": pl.DataFrame(
        [{"drive_id": "d", "ego_id": "e", "actor_id": a, "drive_key": 1, "ego_key": KEYS["e"], "actor_key": KEYS[a],
          "frame": f, "t_s": f * DT, "segment": seg, "holds": p[i]}
         for a, f, p, seg in rows], schema=PHASE_SCHEMA) for i in range(4)}
    frames = run(per_phase("match/phase_frames.sql", 4), phases)
    got = run("match/phase_runs.sql", {"phase_frames": frames, "drive_inputs": DRIVES}, {"max_gap_s": max_gap_s})
    got = sorted(got.select("phase_index", "actor_key", "segment", "start_frame", "end_frame", "jitter").iter_rows())
    gap = math.floor(max_gap_s / DT + 1e-9)
    held = {(i, actor, seg): {f for x, f, p, s in rows if x == actor and s == seg and p[i]}
            for i in range(4) for actor in ("a", "b") for seg in (0, 1)}  # a frame holds if any of its rows does
    expected = sorted(
        # jitter: the run held at fewer than half of its frames
        (i + 1, KEYS[actor], seg, a, b, 2 * sum(a <= f <= b for f in frames) < b - a + 1)
        for (i, actor, seg), frames in held.items() for a, b in bridged_runs(list(frames), gap)
    )
    assert got == expected


# --- sequential phases with duration limits --------------------------------------------------------------------------

def runs_of(flags: list[bool]) -> list[tuple[int, int]]:
    return bridged_runs([i for i, ok in enumerate(flags) if ok])


def oracle_two_phases(p1, p2, ego_frames, lim, gap=0):
    """Chains of phase 1 and phase 2 (the rule of match/chain.sql), walked run by run, trimmed to the maxima
    around the transition and checked against the minima."""
    t = {f: round(f * DT, 6) for f in ego_frames}
    out = []
    for a1, b1 in p1:
        transitions = []
        for a2, b2 in p2:
            if a1 < a2 <= b1 + 1 + gap:
                transitions.append((a2, b2))
            elif a2 <= a1 and b2 >= a1 + 1:
                transitions.append((b1 + 1 if b2 >= b1 + 1 else a1 + 1, b2))
        if not transitions:
            continue
        start2, end2 = min(transitions)
        end1 = start2 - 1
        frames = [f for f in ego_frames if a1 <= f <= end2]
        before = [t[f] for f in frames if f <= end1]
        after = [t[f] for f in frames if f >= start2]
        end1_s = max(before) if before else None
        start2_s = min(after) if after else None
        kept = [f for f in frames
                if (f > end1 or lim["max1"] is None or (end1_s is not None and t[f] >= end1_s - lim["max1"] - 1e-6))
                and (f < start2 or lim["max2"] is None
                     or (start2_s is not None and t[f] <= start2_s + lim["max2"] + 1e-6))]
        if not kept:
            continue
        s1, e1, s2, e2 = max(a1, min(kept)), min(end1, max(kept)), max(start2, min(kept)), min(end2, max(kept))
        ok = all((b - a) * DT >= lo - 1e-6 and (hi is None or (b - a) * DT <= hi + 1e-6)
                 for (a, b), lo, hi in (((s1, e1), lim["min1"], lim["max1"]), ((s2, e2), lim["min2"], lim["max2"])))
        if ok:
            out.append((s1, e1, s2, e2))
    return sorted(out)


LIMIT = st.sampled_from([None, 0.0, 0.3, 1.0])


@PROFILE
@given(n=st.integers(2, 50).flatmap(lambda n: st.tuples(
           st.lists(st.booleans(), min_size=n, max_size=n), st.lists(st.booleans(), min_size=n, max_size=n),
           st.lists(st.booleans(), min_size=n, max_size=n))),
       min1=st.sampled_from([0.0, 0.2, 0.5]), min2=st.sampled_from([0.0, 0.2, 0.5]), max1=LIMIT, max2=LIMIT,
       gap=st.sampled_from([0, 2]))
def test_two_phases_chain_by_the_one_rule_and_trim_to_the_limits(n, min1, min2, max1, max2, gap):
    ok1, ok2, seen = n
    seen = [s or i % 5 == 0 for i, s in enumerate(seen)]  # the ego's own samples, some missing
    ego_frames = [i for i, s in enumerate(seen) if s]
    def jitter(a: int) -> bool:  # some runs flagged as jitter (held at fewer than half their frames): never chained
        return a % 7 == 3

    runs = pl.DataFrame(
        [{"phase_index": k, "drive_key": 1, "ego_key": KEYS["e"], "actor_key": KEYS["a"], "start_frame": a,
          "end_frame": b, "max_gap_frames": gap, "jitter": jitter(a)}
         for k, flags in ((1, ok1), (2, ok2)) for a, b in runs_of(flags)],
        schema={"phase_index": pl.Int64, "drive_key": pl.Int64, "ego_key": pl.Int64, "actor_key": pl.Int64,
                "start_frame": pl.Int64, "end_frame": pl.Int64, "max_gap_frames": pl.Int64, "jitter": pl.Boolean})
    tracks = pl.DataFrame({"drive_id": "d", "actor_id": "e", "drive_key": 1, "actor_key": KEYS["e"],
                           "frame": ego_frames, "t_s": [round(f * DT, 6) for f in ego_frames]},
                          schema={"drive_id": pl.String, "actor_id": pl.String, "drive_key": pl.Int64,
                                  "actor_key": pl.Int64, "frame": pl.Int64, "t_s": pl.Float64})
    tracks = pl.concat([tracks, OTHER_ACTORS], how="diagonal_relaxed")
    values = {"phase_count": 2, "max_gap_s": 0.0, "phase_1_min_duration_s": min1, "phase_2_min_duration_s": min2,
              "phase_1_max_duration_s": max1, "phase_2_max_duration_s": max2, "phase_1_name": "p1", "phase_2_name": "p2"}
    con = duckdb.connect()
    for name, frame in (("phase_runs", runs), ("tracks", tracks), ("drive_inputs", DRIVES)):
        con.register(f"_{name}", frame)
        con.execute(f"create temp table {name} as select * from _{name}")
    materialise(con, "scenario_phases", per_phase("match/scenario_phases.sql", 2), values)
    materialise(con, "chain", "match/chain.sql", values)
    materialise(con, "out", "match/sequential.sql", values)
    got = sorted(con.sql(  # one row per match and phase: each match's two phases side by side
        "select " + ", ".join(f"min(phase_{edge}_frame) filter (where phase_index = {k})"
                              for k in (1, 2) for edge in ("start", "end"))
        + " from out group by start_frame").fetchall())
    lim = {"min1": min1, "min2": min2, "max1": max1, "max2": max2}
    kept = [[r for r in runs_of(flags) if not jitter(r[0])] for flags in (ok1, ok2)]
    assert got == oracle_two_phases(*kept, ego_frames, lim, gap)


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
    buckets = coverage_buckets(SimpleNamespace(name="s", coverage=[item, enum]))
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
          "box_distance_m": dist, "ego_speed_mps": v} for f, (kind, dist, v) in present],
        schema={"drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String, "frame": pl.Int64,
                "t_s": pl.Float64, "actor_kind": pl.String, "box_distance_m": pl.Float64,
                "ego_speed_mps": pl.Float64})  # relations carry the ego's speed (the lean relation)
    tracks = pl.DataFrame([{"drive_id": "d", "actor_id": "e", "frame": f, "t_s": f * dt, "speed_mps": v}
                           for f, (_, _, v) in present],
                          schema={"drive_id": pl.String, "actor_id": pl.String, "frame": pl.Int64, "t_s": pl.Float64,
                                  "speed_mps": pl.Float64})
    tracks = tracks.with_columns(drive_key=pl.lit(1, pl.Int64), actor_key=pl.lit(KEYS["e"], pl.Int64))
    tracks = pl.concat([tracks, OTHER_ACTORS], how="diagonal_relaxed")
    relations = relations.with_columns(drive_key=pl.lit(1, pl.Int64), ego_key=pl.lit(KEYS["e"], pl.Int64),
                                       actor_key=pl.lit(KEYS["c"], pl.Int64))
    drives = pl.DataFrame({"drive_id": ["d"], "drive_key": [1], "dt_s": [dt]})
    con = duckdb.connect()
    for name, frame in (("relations", relations), ("tracks", tracks), ("drive_inputs", drives)):
        con.register(f"_{name}", frame)
        con.execute(f"create temp table {name} as select * from _{name}")
    values = {"sut_minimal_speed_mps": 5 / 3.6, "min_distance_from_cyclist_m": 0.0, "max_distance_from_cyclist_m": 5.0,
              "max_gap_s": 0.0, "phase_count": 1, "phase_1_min_duration_s": 0.0, "phase_1_max_duration_s": max_s,
              "phase_1_name": "cyclist_close"}
    materialise(con, "phase_1", "phases/cyclist_close_to_moving_sut.sql", values)
    for table, query in (("phase_frames", per_phase("match/phase_frames.sql", 1)),
                         ("scenario_phases", per_phase("match/scenario_phases.sql", 1)),
                         ("phase_runs", "match/phase_runs.sql"), ("chain", "match/chain.sql"),
                         ("out", "match/sequential.sql")):
        materialise(con, table, query, values)
    got = sorted(con.sql("select start_frame, end_frame from out").fetchall())

    holds = [f for f, (kind, dist, v) in present if kind == "cyclist" and 0.0 <= dist <= 5.0 and v >= 5 / 3.6]
    span = math.floor(max_s / dt + 1e-9) + 1  # frames a piece may span
    expected = sorted((a, min(a + span - 1, b)) for start, b in bridged_runs(holds) for a in range(start, b + 1, span))
    assert got == expected
    assert all((b - a) * dt <= max_s + 1e-9 for a, b in got)  # no piece lasts longer than the maximum
