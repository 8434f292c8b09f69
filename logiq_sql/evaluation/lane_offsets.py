"""Print a seeded sample of a scenario's matches on real drives as offsets from the lane map, to be checked by eye.

    python -m logiq_sql.evaluation.lane_offsets --db demo.duckdb --scenario sut_cut_out [--n 12] [--seed 36]

For each sampled match, every 0.5 s from half a second before it to half a second after: the signed distance of
the ego's and the actor's centres from the centre line of the lane the ego is in at the match's start (and the
lanes that continue it or lead into it, up to four links each way; left positive), and how far the actor is ahead along that line. Read
against the lane map, not the ego's heading: a road that bends fools a drawing in the ego's frame (docs/
evaluation.md, "The three wrong cut-outs measured against the lane map"). A cut-out is the ego's offset moving by
about a lane while the actor's stays; a cut-in the actor's moving onto the ego's line while the ego's stays; a
follower a negative `along` with both offsets within the lane. The sample is ``random.Random(seed).sample`` of the
matches sorted by (drive, ego, actor, start); the lines marked ``*`` are inside the match.
"""

from __future__ import annotations

import argparse
import random
import sys

import shapely
from shapely.ops import linemerge

from logiq_sql.storage.db import connect

STEP_FRAMES = 5  # every 0.5 s at NGSIM's and nuScenes' 10 Hz
LINKS = 4  # the lanes that continue the start lane, and those that lead into it


def _line(con, drive_id: str, lane_id: str) -> shapely.LineString:
    """The centre line of ``lane_id`` and of the lanes that continue it or lead into it, as one line (the longest
    piece where they branch)."""
    rows = con.sql(f"""
        with recursive linked (lane_id, links, way) as (
            select $lane, 0, 1
            union all
            select $lane, 0, -1
            union all
            select case when a.way = 1 then s.successor_id else s.lane_id end, a.links + 1, a.way
            from linked as a
            inner join lane_successors as s
                on (a.way = 1 and s.lane_id = a.lane_id) or (a.way = -1 and s.successor_id = a.lane_id)
            inner join drive_inputs as d on d.map_id = s.map_id and d.drive_id = $drive
            where a.links < {LINKS}
        )
        select distinct l.centerline_wkt
        from lanes as l
        inner join drive_inputs as d on d.map_id = l.map_id and d.drive_id = $drive
        where l.lane_id in (select lane_id from linked)""", params={"lane": lane_id, "drive": drive_id}).fetchall()
    merged = linemerge([shapely.from_wkt(w) for (w,) in rows])
    return merged if merged.geom_type == "LineString" else max(merged.geoms, key=lambda g: g.length)


def _offset(line: shapely.LineString, x: float, y: float) -> tuple[float, float]:
    """(signed distance from the line, left positive; position along it)."""
    point = shapely.Point(x, y)
    along = line.project(point)
    a, b = line.interpolate(max(along - 1.0, 0.0)), line.interpolate(min(along + 1.0, line.length))
    left = (b.x - a.x) * (y - a.y) - (b.y - a.y) * (x - a.x) > 0
    distance = point.distance(line)
    return (distance if left else -distance) or 0.0, along  # on the line: 0, not -0


def report(db: str, scenario: str, n: int, seed: int) -> str:
    out = []
    with connect(db, read_only=True) as con:
        keys = con.sql("select match_id, drive_id, ego_id, actor_id, start_s, end_s, start_frame from matches "
                       "where scenario = $s order by drive_id, ego_id, actor_id, start_s",
                       params={"s": scenario}).fetchall()
        for match_id, drive, ego, actor, start_s, end_s, start_frame in random.Random(seed).sample(
                keys, min(n, len(keys))):
            phases = con.sql("select phase, start_s, end_s from match_phases where match_id = $m order by phase_index",
                             params={"m": match_id}).fetchall()
            out.append(f"=== {drive} ego {ego} actor {actor} {start_s:.1f}-{end_s:.1f} s: "
                       + ", ".join(f"{p} {a:.1f}-{b:.1f}" for p, a, b in phases))
            lane = con.sql("select lane_id from ego_lanes where drive_id = $d and ego_id = $e and frame = $f",
                           params={"d": drive, "e": ego, "f": start_frame}).fetchall()
            if not lane or lane[0][0] is None:
                out.append("    the ego is in no lane at the start")
                continue
            line = _line(con, drive, lane[0][0])
            rows = con.sql(f"""select e.t_s, e.x_m, e.y_m, a.x_m, a.y_m from tracks as e
                               inner join tracks as a on a.drive_id = e.drive_id and a.frame = e.frame
                               where e.drive_id = $d and e.actor_id = $e and a.actor_id = $a
                                 and e.t_s between $s0 - 0.5 and $s1 + 0.5 and e.frame % {STEP_FRAMES} = 0
                               order by e.t_s""",
                           params={"d": drive, "e": ego, "a": actor, "s0": start_s, "s1": end_s}).fetchall()
            for t, x, y, ax, ay in rows:
                (ego_off, ego_at), (actor_off, actor_at) = _offset(line, x, y), _offset(line, ax, ay)
                inside = "*" if start_s - 1e-6 <= t <= end_s + 1e-6 else " "
                out.append(f"  {inside}{t:5.1f} s  ego {ego_off:5.1f} m  actor {actor_off:5.1f} m  "
                           f"actor ahead {actor_at - ego_at:6.1f} m")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", required=True)
    parser.add_argument("--scenario", required=True)
    parser.add_argument("--n", type=int, default=12)
    parser.add_argument("--seed", type=int, default=36)
    args = parser.parse_args(argv)
    print(report(args.db, args.scenario, args.n, args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
