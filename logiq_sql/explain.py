"""Why a scenario did not match an (ego, actor) pair: the first phase or condition that failed, with values.

For scenarios whose phases come from one per-frame query (``[match] frames``), each phase lists its
conditions in the scenario file. ``explain`` reruns the scenario's steps for one drive and the chosen egos
(read-only: nothing is written to the file) and reads, per pair, the chain of phases that got furthest
(``queries/match/chain.sql``, the same chains the matcher completes):

    phases_reached   how many phases that chain got through (all of them: the pair matched)
    failed_phase     the phase that could not begin (phase 1 when it never held)
    at_s, at_frame   when it was needed: the frame right after the last phase reached stopped holding; when
                     phase 1 never held, the frame at which most of phase 1's conditions held
    failed           the conditions of failed_phase that are false there, each with its measured value and
                     the test it applies (the parameter values are in ``parameters``)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import polars as pl

from logiq_sql import db, units
from logiq_sql.errors import ScenarioError
from logiq_sql.match import (
    DEFAULT_RELATION_RANGE,
    parse_ego,
    phase_steps,
    prepare_relations,
    resolve_scenarios,
    run_values,
)
from logiq_sql.scenario import Scenario
from logiq_sql.sql import materialise

# per pair: the furthest chain, and the frame at which its next phase was needed
_PROGRESS = """
with best as (
    select
        drive_id, ego_id, actor_id, phase_index, island_end_frame,
        row_number() over (partition by drive_id, ego_id, actor_id order by phase_index desc, path_key) as rank
    from chain
),
pairs as (select distinct drive_id, ego_id, actor_id from phase_frames),
scored as (
    -- where phase 1 never held: the frame with the most phase-1 conditions true, earliest first
    select drive_id, ego_id, actor_id, frame,
        row_number() over (partition by drive_id, ego_id, actor_id order by score desc, frame) as rank
    from (select *, {score} as score from phase_frames) as s
)
select
    p.drive_id, p.ego_id, p.actor_id,
    coalesce(b.phase_index, 0) as phases_reached,
    coalesce(b.island_end_frame + 1, s.frame) as at_frame
from pairs as p
left join best as b
    on p.drive_id = b.drive_id and p.ego_id = b.ego_id and p.actor_id = b.actor_id and b.rank = 1
left join scored as s
    on p.drive_id = s.drive_id and p.ego_id = s.ego_id and p.actor_id = s.actor_id and s.rank = 1
"""


@dataclass
class Explanation:
    pairs: pl.DataFrame  # one row per (ego, actor): phases_reached, failed_phase, at_s, failed
    parameters: dict[str, str]  # the scenario's parameter values, as written

    def text(self) -> str:
        lines = []
        for r in self.pairs.iter_rows(named=True):
            head = f"ego {r['ego_id']}, actor {r['actor_id']}: {r['phases_reached']} of {r['phase_count']} phases"
            if r["failed_phase"] is None:
                lines.append(head + " -- matched")
            elif r["at_s"] is None:
                lines.append(f"{head}; {r['failed_phase']} could not begin at frame {r['at_frame']}: the pair is no "
                             "longer near the same junction there")
            else:
                lines.append(f"{head}; {r['failed_phase']} could not begin at t = {r['at_s']:.2f} s "
                             f"(frame {r['at_frame']}):")
                lines += [f"    {f}" for f in r["failed"]]
        lines.append("parameters: " + ", ".join(f"{k} = {v}" for k, v in sorted(self.parameters.items())))
        return "\n".join(lines)


def _shown(column: str, schema: pl.Schema) -> pl.Expr:
    value = pl.col(column).round(3) if schema[column].is_float() else pl.col(column)
    return value.cast(pl.String).fill_null("NULL")


def _failed(s: Scenario, schema: pl.Schema) -> pl.Expr:
    """Per row, the false conditions of the phase that could not begin, as text."""
    by_phase = []
    for k, phase in enumerate(s.phases):
        texts = [pl.when(~pl.col(c.name).fill_null(False)).then(pl.format(
                    f"{c.name} is false: {c.value} = {{}}, needs {c.test}", _shown(c.value, schema)))
                 for c in phase.conditions]
        by_phase.append(pl.when(pl.col("phases_reached") == k).then(pl.concat_list(texts).list.drop_nulls()))
    return pl.coalesce(by_phase).fill_null(pl.lit([], pl.List(pl.String)))


def explain(db_path: str | Path, scenario: str, drive: str, ego: str, actor: str | None = None,
            overrides: dict[str, str] | None = None, relation_range: str = DEFAULT_RELATION_RANGE) -> Explanation:
    """Explain, for each (ego, actor) pair of ``drive`` near one another in a junction, how far the scenario got."""
    (s,) = resolve_scenarios([scenario], overrides or {})
    if not s.frames_query or not all(p.conditions for p in s.phases):
        raise ScenarioError(f"explain: scenario '{s.name}' has per-phase queries without listed conditions; "
                            "explain covers scenarios whose phases list their conditions ([match] frames).")
    con = db.open_for_read(db_path)
    try:
        known = [r[0] for r in con.execute("select drive_id from drive_inputs").fetchall()]
        if drive not in known:
            raise ScenarioError(f"explain --drive {drive}: no such drive in {db_path}.")
        con.register("run_drives", pl.DataFrame({"drive_id": [drive]}))
        values = run_values(s, parse_ego(ego), units.parse(relation_range, "length", "--relation-range"))
        prepare_relations(con, [s], values)
        for table, rel in phase_steps(s)[:-1]:
            materialise(con, table, rel, values)
        score = " + ".join(f"cast(coalesce({c.name}, false) as integer)" for c in s.phases[0].conditions)
        progress = con.sql(_PROGRESS.format(score=score)).pl()
        frames = con.sql("select * from phase_frames").pl()
    finally:
        con.close()
    at = frames.unique(["ego_id", "actor_id", "frame"], keep="first", maintain_order=True).rename({"frame": "at_frame"})
    pairs = progress.join(at, on=["drive_id", "ego_id", "actor_id", "at_frame"], how="left")
    if actor is not None:
        pairs = pairs.filter(pl.col("actor_id") == actor)
        if pairs.is_empty():
            raise ScenarioError(f"explain --actor {actor}: the actor is never near the ego in the same junction "
                                f"in drive {drive} (or is not within --relation-range).")
    n = len(s.phases)
    names = pl.Series([p.name for p in s.phases])
    pairs = pairs.select(
        "ego_id", "actor_id", pl.lit(n, pl.Int64).alias("phase_count"), pl.col("phases_reached").cast(pl.Int64),
        pl.when(pl.col("phases_reached") < n).then(pl.col("phases_reached").replace_strict(
            list(range(n)), names.to_list(), default=None)).alias("failed_phase"),
        pl.when(pl.col("phases_reached") < n).then(pl.col("at_frame")).alias("at_frame"),
        pl.when(pl.col("phases_reached") < n).then(pl.col("t_s")).alias("at_s"),
        pl.when(pl.col("phases_reached") < n).then(_failed(s, pairs.schema)).alias("failed"),
    )
    return Explanation(pairs.sort(["phases_reached", "ego_id", "actor_id"], descending=[True, False, False]),
                       {p.name: p.text or "unset" for p in s.params.values()})
