"""Why a scenario did or did not match an (ego, actor) pair: how far its phases chained, the conditions that
failed with their measured values, and the gaps and flickers that were bridged.

Works for every scenario: each phase is a query of per-frame conditions (the phase contract, docs/scenarios.md)
and lists its conditions in the scenario file. ``explain`` reruns the scenario's steps for one drive and the
chosen egos (read-only: nothing is written to the file) and reads, per pair, the chain of phases that got
furthest (``queries/match/chain.sql``, the same chains the matcher completes):

    phases_reached   how many phases that chain got through (all of them: the phases chained)
    matched          the pair has a match (a complete chain whose phases also fit their durations)
    failed_phase     the phase that could not begin (phase 1 when it never held; NULL when matched)
    at_s, at_frame   when it was needed: the frame right after the last phase reached stopped holding; when
                     phase 1 never held, the frame at which most of phase 1's conditions held and, of several,
                     the one at which the two are closest (box to box): the moment a person looks at (a
                     cyclist's closest pass, not the first frame it was seen far away)
    failed           the conditions of failed_phase that are false there, each with its measured value and
                     the test it applies (the parameter values are in ``parameters``)
    in_jitter        failed_phase holds at that frame, but only within a run dropped as jitter (below)
    bridged          the runs of the pair's phases in which an interruption of at most max_gap (a missing
                     frame, or a condition flickering false) was bridged (``phase_runs.bridged_frames``), and
                     those dropped as jitter because they held at fewer than half of their frames
                     (``phase_runs.jitter``)
    chained          when the phases chained but no match fits their durations: each phase of the earliest
                     complete chain, its span and the limits it must meet
    unmatched        for a matched pair, the stretches of frames at which phase 1's query has a row for the pair
                     (it is a candidate) but phase 1 does not hold and no match covers them, each with the
                     conditions that are false at its first frame: why the rest of the pair's time is no match
                     (a follower whose first seconds are not matched)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import polars as pl

from logiq_sql.core.errors import ScenarioError, arg
from logiq_sql.core.sql import materialise, registered
from logiq_sql.matching.runner import prepare_relations
from logiq_sql.spec.plan import (
    DEFAULT_RELATION_RANGE,
    parse_ego,
    phase_steps,
    relation_range_m,
    resolve_scenarios,
    run_values,
)
from logiq_sql.spec.scenario import Scenario, ScenarioPath
from logiq_sql.storage import db

# the pairs' ids by their integer keys, from the phases' rows (the phase contract returns both)
_PAIR_IDS = """
create or replace temp table _pair_ids as
select distinct drive_key, ego_key, actor_key, drive_id, ego_id, actor_id from ({phases})
"""
# the match steps' rows with the pair's ids beside its integer keys (they join and group on the keys only)
_WITH_IDS = """
create or replace temp view {table}_ids as
select i.drive_id, i.ego_id, i.actor_id, s.*
from {table} as s
inner join _pair_ids as i on s.drive_key = i.drive_key and s.ego_key = i.ego_key and s.actor_key = i.actor_key
"""
# per pair: the furthest chain, and the frame at which its next phase was needed
_PROGRESS = """
with best as (
    select
        drive_id, ego_id, actor_id, phase_index, run_end_frame,
        row_number() over (partition by drive_id, ego_id, actor_id order by phase_index desc, path_key) as rank
    from chain_ids
),
pairs as (select distinct drive_id, ego_id, actor_id from phase_1),
scored as (
    -- where phase 1 never held: the frame with the most phase-1 conditions true, the two closest first
    select s.drive_id, s.ego_id, s.actor_id, s.frame,
        row_number() over (
            partition by s.drive_id, s.ego_id, s.actor_id order by s.score desc, r.box_distance_m nulls last, s.frame
        ) as rank
    from (select *, {score} as score from phase_1) as s
    left join relations as r
        on s.drive_id = r.drive_id and s.ego_id = r.ego_id and s.actor_id = r.actor_id and s.frame = r.frame
)
select
    p.drive_id, p.ego_id, p.actor_id,
    coalesce(b.phase_index, 0) as phases_reached,
    coalesce(b.run_end_frame + 1, s.frame) as at_frame,
    exists (select 1 from scenario_match as m
            where m.drive_id = p.drive_id and m.ego_id = p.ego_id and m.actor_id = p.actor_id) as matched
from pairs as p
left join best as b
    on p.drive_id = b.drive_id and p.ego_id = b.ego_id and p.actor_id = b.actor_id and b.rank = 1
left join scored as s
    on p.drive_id = s.drive_id and p.ego_id = s.ego_id and p.actor_id = s.actor_id and s.rank = 1
"""
# per pair: the phases of its earliest complete chain, before the duration limits trim or reject it (frames *
# dt_s: a phase boundary may fall on a missing frame)
_CHAINED = """
with complete as (
    select drive_id, ego_id, actor_id, min(path_key) as path_key
    from chain_ids where phase_index = $phase_count group by drive_id, ego_id, actor_id
),
steps as (
    select c.drive_id, c.ego_id, c.actor_id, c.phase_index, c.phase_start_frame,
        coalesce(lead(c.phase_start_frame) over (
            partition by c.drive_id, c.ego_id, c.actor_id order by c.phase_index) - 1, c.run_end_frame)
            as phase_end_frame
    from chain_ids as c
    inner join complete as k
        on c.drive_id = k.drive_id and c.ego_id = k.ego_id and c.actor_id = k.actor_id
        and starts_with(k.path_key, c.path_key)
)
select s.drive_id, s.ego_id, s.actor_id, s.phase_index, s.phase_start_frame * d.dt_s as start_s,
    s.phase_end_frame * d.dt_s as end_s
from steps as s inner join drive_inputs as d on s.drive_id = d.drive_id
order by s.drive_id, s.ego_id, s.actor_id, s.phase_index
"""
# per matched pair: the stretches of phase 1's rows at which phase 1 does not hold and no match covers the frame
_UNMATCHED = """
with candidate as (
    select distinct p.drive_id, p.ego_id, p.actor_id, p.frame, p.t_s
    from phase_1 as p
    inner join (select distinct drive_id, ego_id, actor_id from scenario_match) as k
        on p.drive_id = k.drive_id and p.ego_id = k.ego_id and p.actor_id = k.actor_id
    where not coalesce(p.holds, false)
        and not exists (select 1 from scenario_match as m
                        where m.drive_id = p.drive_id and m.ego_id = p.ego_id and m.actor_id = p.actor_id
                            and p.frame between m.start_frame and m.end_frame)
),
stretches as (
    select *, frame - row_number() over (partition by drive_id, ego_id, actor_id order by frame) as stretch
    from candidate
)
select drive_id, ego_id, actor_id, min(frame) as start_frame, max(frame) as end_frame, min(t_s) as start_s,
    max(t_s) as end_s
from stretches group by drive_id, ego_id, actor_id, stretch
"""
_BRIDGED = """
select drive_id, ego_id, actor_id, phase_index, start_frame, end_frame, start_s, end_s, bridged_frames, jitter
from phase_runs_ids where bridged_frames > 0 order by drive_id, ego_id, actor_id, phase_index, start_frame
"""


@dataclass
class Explanation:
    pairs: pl.DataFrame  # one row per (ego, actor): phases_reached, matched, failed_phase, at_s, failed, in_jitter, bridged, chained, unmatched
    parameters: dict[str, str]  # the scenario's parameter values, as written

    def text(self) -> str:
        lines = []
        for r in self.pairs.iter_rows(named=True):
            head = f"ego {r['ego_id']}, actor {r['actor_id']}: {r['phases_reached']} of {r['phase_count']} phases"
            if r["matched"]:
                lines.append(head + " -- matched")
                lines += [f"    {u}" for u in r["unmatched"]]
            elif r["failed_phase"] is None:
                lines.append(head + " chained, but no chain fits the phases' duration limits (min/max_duration); "
                             "the earliest chain, before the first phase is trimmed to its last max and the last "
                             "to its first max:")
                lines += [f"    {c}" for c in r["chained"]]
            elif r["at_s"] is None:
                lines.append(f"{head}; {r['failed_phase']} could not begin at frame {r['at_frame']}: no row of that "
                             "phase's query there (the pair is not a candidate at that frame, e.g. too far apart)")
            else:
                lines.append(f"{head}; {r['failed_phase']} could not begin at t = {r['at_s']:.2f} s "
                             f"(frame {r['at_frame']}):")
                lines += [f"    {f}" for f in r["failed"]] or [
                    "    all its conditions hold at this frame, but only in a run dropped as jitter (below)"
                    if r["in_jitter"] else
                    "    all its conditions hold at this frame, but the run it holds in does not continue the chain"]
            lines += [f"    bridged: {b}" for b in r["bridged"]]
        lines.append("parameters: " + ", ".join(f"{k} = {v}" for k, v in sorted(self.parameters.items())))
        return "\n".join(lines)


def _shown(column: str, schema: pl.Schema) -> pl.Expr:
    value = pl.col(column).round(3) if schema[column].is_float() else pl.col(column)
    return value.cast(pl.String).fill_null("NULL")


def _failed(phase_index: int, s: Scenario, schema: pl.Schema) -> pl.Expr:
    """Per row of phase ``phase_index``'s table, its false conditions as text."""
    phase = s.phases[phase_index]
    texts = [pl.when(~pl.col(c.name).fill_null(False)).then(pl.format(
                f"{c.name} is false: {c.value} = {{}}, needs {c.test}", _shown(c.value, schema)))
             for c in phase.conditions]
    if not texts:
        return pl.lit([], pl.List(pl.String))
    return pl.concat_list(texts).list.drop_nulls()


def _read_steps(con, s: Scenario, values: dict[str, object]):
    """The scenario's steps on the drive of ``run_drives``, and what explain reads of them: the furthest chain per
    pair, the bridged runs, the complete chains, phase 1's rows in the unmatched stretches, and per phase the row
    at the frame it was needed."""
    prepare_relations(con, [s], values, every_kind=True)  # the pairs it cannot match, too
    for table, rel in phase_steps(s):
        materialise(con, table, rel, values)
    con.execute(_PAIR_IDS.format(phases=" union all ".join(
        f"select drive_key, ego_key, actor_key, drive_id, ego_id, actor_id from phase_{i}"
        for i in range(1, len(s.phases) + 1))))
    for table in ("chain", "phase_runs"):
        con.execute(_WITH_IDS.format(table=table))
    score = " + ".join(f"cast(coalesce({c.name}, false) as integer)" for c in s.phases[0].conditions)
    progress = con.sql(_PROGRESS.format(score=score)).pl()
    bridged = con.sql(_BRIDGED).pl()
    chained = con.sql(_CHAINED, params={"phase_count": len(s.phases)}).pl()
    with registered(con, "_stretches", con.sql(_UNMATCHED).pl()):
        stretch_rows = con.sql("select p.*, u.start_s, u.end_s, u.start_frame, u.end_frame from phase_1 as p "
                               "join _stretches as u on p.drive_id = u.drive_id and p.ego_id = u.ego_id "
                               "and p.actor_id = u.actor_id and p.frame between u.start_frame and u.end_frame "
                               "order by p.frame").pl()
    stretch_rows = stretch_rows.unique(["ego_id", "actor_id", "frame"], keep="first", maintain_order=True)
    # the row of each phase's table at the frame it was needed (several rows per frame: the first)
    needed = []
    for k in range(len(s.phases)):
        want = progress.filter(pl.col("phases_reached") == k).select("drive_id", "ego_id", "actor_id", "at_frame")
        # the frame right after phase k stopped holding, else (the drive or the pair ends there) its last frame
        with registered(con, "_want", want):
            rows = con.sql(f"select p.*, w.at_frame as wanted_frame from phase_{k + 1} as p join _want as w "
                           "on p.drive_id = w.drive_id and p.ego_id = w.ego_id and p.actor_id = w.actor_id "
                           "and p.frame in (w.at_frame, w.at_frame - 1) order by p.frame desc").pl()
        rows = rows.unique(["ego_id", "actor_id"], keep="first", maintain_order=True)
        needed.append(rows.select("drive_id", "ego_id", "actor_id", pl.col("wanted_frame").alias("at_frame"),
                                  pl.col("frame").alias("shown_frame"), "t_s",
                                  _failed(k, s, rows.schema).alias("failed")))
    return progress, bridged, chained, stretch_rows, needed


def explain(db_path: str | Path, scenario: str, drive: str, ego: str, *, actor: str | None = None,
            overrides: dict[str, str] | None = None, relation_range: str = DEFAULT_RELATION_RANGE,
            scenario_path: ScenarioPath = None, ego_kinds: str | None = None) -> Explanation:
    """Explain, for each (ego, actor) pair of ``drive`` that phase 1's query considers, how far the scenario
    got and why it stopped there."""
    (s,) = resolve_scenarios([scenario], overrides or {}, scenario_path)
    if not all(p.conditions for p in s.phases):
        missing = next(p.name for p in s.phases if not p.conditions)
        raise ScenarioError(f"explain: phase {missing} of {s.path} lists no conditions; list them "
                            "(`conditions = [{ name, value, test }]`, docs/scenarios.md) to explain it.")
    con = db.open_current(db_path)
    try:
        known = [r[0] for r in con.execute("select drive_id from drive_inputs").fetchall()]
        if drive not in known:
            raise ScenarioError(f"explain {arg('drive', drive)}: no such drive in {db_path}.")
        values = run_values(s, parse_ego(ego, ego_kinds), relation_range_m(relation_range))
        with registered(con, "run_drives", pl.DataFrame({"drive_id": [drive]})):
            progress, bridged, chained, stretch_rows, needed = _read_steps(con, s, values)
    finally:
        con.close()
    at = pl.concat(needed) if needed else None
    pairs = progress.join(at, on=["drive_id", "ego_id", "actor_id", "at_frame"], how="left")
    if actor is not None:
        pairs = pairs.filter(pl.col("actor_id") == actor)
        if pairs.is_empty():
            raise ScenarioError(f"explain {arg('actor', actor)}: phase 1's query ({s.phases[0].query}) has no row "
                                f"for this actor and ego in drive {drive} (too far apart, or not within "
                                f"{arg('relation_range', relation_range)}).")
    names = [p.name for p in s.phases]
    indices = list(range(1, len(names) + 1))  # phase_index of each phase
    phase_name = pl.col("phase_index").replace_strict(indices, names, default="?")
    bridged_text = bridged.select(
        "ego_id", "actor_id",
        pl.format("{} frames {}-{} ({} s to {} s): {} frame(s) missing or not holding, {}",
                  phase_name,
                  "start_frame", "end_frame", pl.col("start_s").round(2), pl.col("end_s").round(2),
                  "bridged_frames",
                  pl.when("jitter").then(pl.lit("more than it held: dropped as jitter")).otherwise(pl.lit("bridged"))
                  ).alias("text"),
    ).group_by("ego_id", "actor_id", maintain_order=True).agg(pl.col("text").alias("bridged"))
    def limit(name: str | None, default: str) -> str:
        return s.params[name].text if name and s.params[name].text else default

    limits = [f"needs {limit(p.min_duration, '0s')} to {limit(p.max_duration, 'any length')}" for p in s.phases]
    chained_text = chained.select(
        "ego_id", "actor_id",
        pl.format("{} {} s to {} s ({} s; {})",
                  phase_name,
                  pl.col("start_s").round(2), pl.col("end_s").round(2), (pl.col("end_s") - pl.col("start_s")).round(2),
                  pl.col("phase_index").replace_strict(indices, limits, default="?")
                  ).alias("text"),
    ).group_by("ego_id", "actor_id", maintain_order=True).agg(pl.col("text").alias("chained"))
    # per stretch, each condition that is false in it: at how many of its frames, and its value where it first is;
    # the most frequent first, in the order the scenario lists them
    stretch = ["ego_id", "actor_id", "start_frame"]
    false_at = stretch_rows.select(*stretch, "end_frame", "start_s", "end_s", "t_s",
                                   _failed(0, s, stretch_rows.schema).alias("failed")).explode("failed")
    false_at = false_at.with_columns(
        pl.col("failed").fill_null("a condition the scenario file does not list"),
        frames=pl.col("end_frame") - pl.col("start_frame") + 1)
    unmatched_text = false_at.group_by(*stretch, "end_frame", "start_s", "end_s", "frames",
                                       pl.col("failed").str.extract(r"^(\S+)", 1).alias("condition")).agg(
        pl.len().alias("false_frames"), pl.col("failed").first(), pl.col("t_s").first()
    ).with_columns(listed=pl.col("condition").replace_strict(
        [c.name for c in s.phases[0].conditions], list(range(len(s.phases[0].conditions))), default=None)
    ).sort(*stretch, "false_frames", "listed", descending=[False, False, False, True, False]).group_by(
        *stretch, "end_frame", "start_s", "end_s", "frames", maintain_order=True).agg(
        pl.format("{} at {} of {} frames (first at {} s: {})", "condition", "false_frames", "frames",
                  pl.col("t_s").round(2), "failed").alias("why")
    ).select(
        "ego_id", "actor_id",
        pl.format("not matched from {} s to {} s (frames {}-{}): {} does not hold: {}",
                  pl.col("start_s").round(2), pl.col("end_s").round(2), "start_frame", "end_frame",
                  pl.lit(names[0]), pl.col("why").list.join("; ")).alias("text"),
    ).group_by("ego_id", "actor_id", maintain_order=True).agg(pl.col("text").alias("unmatched"))
    # the pairs whose needed phase holds at the frame shown only within a run dropped as jitter
    keys = ["ego_id", "actor_id", "phases_reached"]
    pairs = pairs.with_columns(pl.col("phases_reached").cast(pl.Int64))
    in_jitter = pairs.select(*keys, "shown_frame").join(
        bridged.filter("jitter").select("ego_id", "actor_id", "start_frame", "end_frame",
                                        phases_reached=pl.col("phase_index").cast(pl.Int64) - 1),
        on=keys).filter(pl.col("shown_frame").is_between("start_frame", "end_frame")).select(keys).unique()
    pairs = pairs.join(in_jitter.with_columns(in_jitter=pl.lit(True)), on=keys, how="left")
    n = len(s.phases)
    open_ = (pl.col("phases_reached") < n) & ~pl.col("matched")
    pairs = pairs.join(bridged_text, on=["ego_id", "actor_id"], how="left").join(
        chained_text, on=["ego_id", "actor_id"], how="left").join(
        unmatched_text, on=["ego_id", "actor_id"], how="left").select(
        "ego_id", "actor_id", pl.lit(n, pl.Int64).alias("phase_count"), "phases_reached",
        "matched",
        pl.when(open_).then(pl.col("phases_reached").replace_strict(
            list(range(n)), names, default=None)).alias("failed_phase"),
        pl.when(open_).then(pl.coalesce("shown_frame", "at_frame")).alias("at_frame"),
        pl.when(open_).then(pl.col("t_s")).alias("at_s"),
        pl.when(open_).then(pl.col("failed").fill_null(pl.lit([], pl.List(pl.String))))
        .otherwise(pl.lit([], pl.List(pl.String))).alias("failed"),
        pl.col("in_jitter").fill_null(False),
        pl.col("bridged").fill_null(pl.lit([], pl.List(pl.String))),
        pl.col("chained").fill_null(pl.lit([], pl.List(pl.String))),
        pl.col("unmatched").fill_null(pl.lit([], pl.List(pl.String))),
    )
    return Explanation(pairs.sort(["matched", "phases_reached", "ego_id", "actor_id"],
                                  descending=[True, True, False, False]),
                       {p.name: p.text or "unset" for p in s.params.values()})
