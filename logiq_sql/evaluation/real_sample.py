"""Draw a seeded random sample of a scenario's matches and non-matches on real drives, to be checked by eye.

    python -m logiq_sql.evaluation.real_sample --db ngsim.duckdb --scenario sut_cut_out --out sample/ [--n 20]

Real drives have no ground truth, so the matcher is checked by looking: ``--n`` matches of the scenario, drawn
with ``plots.birds_eye`` (the ego's and the actor's paths, the phases' starts), and ``--n`` non-matches, drawn
here (in the road's frame, lateral axis stretched): the ego's lane changes (a new lane run in ``ego_lanes``) that no match of the scenario covers, with the
ego's path (a dot each second, the lane change marked) and every road user within 40 m of it over the same
seconds. Each PNG is named after its drive, ego and time; ``sample.csv`` lists them with an empty ``verdict``
column for the reader. The sample is ``polars.DataFrame.sample(seed=...)`` of the candidates sorted by key.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import polars as pl
import shapely
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from logiq_sql.outputs.plots import ACTOR_COLOUR, EGO_COLOUR, birds_eye
from logiq_sql.storage.db import connect

NEAR_M = 40.0


def candidates(con, scenario: str) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(matches of ``scenario``, the ego lane changes no match of it covers), each sorted by key."""
    matches = con.sql("select match_id, drive_id, ego_id, actor_id, start_s, end_s from matches "
                      "where scenario = $s order by drive_id, ego_id, start_s", params={"s": scenario}).pl()
    changes = con.sql("""
        select l.drive_id, l.ego_id, l.t_s as change_s, l.lane_change_side
        from ego_lanes as l
        where l.lane_change_side is not null
          and not exists (select 1 from matches as m
                          where m.scenario = $s and m.drive_id = l.drive_id and m.ego_id = l.ego_id
                            and l.t_s between m.start_s and m.end_s)
        order by l.drive_id, l.ego_id, l.t_s""", params={"s": scenario}).pl()
    return matches, changes


def draw_change(con, drive_id: str, ego_id: str, change_s: float, side: str) -> Figure:
    """The ego's path (dots each second, the lane change a star) and every road user within ``NEAR_M``, in the
    road's frame: the x axis along the ego's mean direction of travel, the y axis to its left, stretched 4x so
    that lanes are horizontal bands and a lane change is plain to see."""
    tracks = con.sql("select actor_id, t_s, x_m, y_m from tracks where drive_id = $d order by actor_id, t_s",
                     params={"d": drive_id}).pl()
    ego = tracks.filter(pl.col("actor_id") == ego_id)
    near = (tracks.join(ego.select("t_s", ex="x_m", ey="y_m"), on="t_s")
            .filter(((pl.col("x_m") - pl.col("ex")) ** 2 + (pl.col("y_m") - pl.col("ey")) ** 2).sqrt() < NEAR_M)
            ["actor_id"].unique())
    ox, oy = float(ego["x_m"][0]), float(ego["y_m"][0])
    dx, dy = float(ego["x_m"][-1]) - ox, float(ego["y_m"][-1]) - oy
    ux, uy = dx / np.hypot(dx, dy), dy / np.hypot(dx, dy)

    def road(x, y):  # along, left of the ego's direction of travel
        x, y = np.asarray(x) - ox, np.asarray(y) - oy
        return x * ux + y * uy, -x * uy + y * ux

    others = tracks.filter(pl.col("actor_id").is_in(near.implode()) & (pl.col("actor_id") != ego_id))
    s0, s1 = road(ego["x_m"], ego["y_m"])[0].min() - 30, road(ego["x_m"], ego["y_m"])[0].max() + 30
    map_id = con.sql("select map_id from drive_inputs where drive_id = $d", params={"d": drive_id}).fetchall()[0][0]
    lanes = con.sql("select polygon_wkt from lanes where map_id = $m", params={"m": map_id}).pl()
    fig = Figure(figsize=(13, 5), layout="constrained")
    ax = fig.add_subplot()
    rings = [np.column_stack(road(*shapely.get_coordinates(g).T)) for g in
             shapely.get_exterior_ring(shapely.get_parts(shapely.from_wkt(lanes["polygon_wkt"].to_numpy())))]
    ax.add_collection(PolyCollection(rings, facecolor="#ececec", edgecolor="#8a8a8a", linewidth=0.6, zorder=1))
    for (actor,), path in others.group_by("actor_id", maintain_order=True):
        a, b = road(path["x_m"], path["y_m"])
        ax.plot(a, b, color=ACTOR_COLOUR, linewidth=0.8, alpha=0.45, zorder=2)
        at = path.filter((pl.col("t_s") - change_s).abs() < 0.05)
        if at.height:
            a, b = road(at["x_m"], at["y_m"])
            ax.scatter(a, b, s=16, color=ACTOR_COLOUR, zorder=3)
            ax.annotate(str(actor), (a[0], b[0]), fontsize=7, zorder=4)
    a, b = road(ego["x_m"], ego["y_m"])
    ax.plot(a, b, color=EGO_COLOUR, linewidth=2.5, zorder=5, label=f"ego {ego_id} (others: red, dots at the change)")
    sec = ego.with_row_index("i").filter(((pl.col("t_s") * 10).round() % 10) == 0)["i"].to_numpy()
    ax.scatter(a[sec], b[sec], s=14, color="black", zorder=6)
    for i in sec:
        ax.annotate(f"{ego['t_s'][int(i)]:.0f}s", (a[i], b[i]), fontsize=7, xytext=(0, 5), textcoords="offset points")
    i = int(np.argmin(np.abs(ego["t_s"].to_numpy() - change_s)))
    ax.scatter([a[i]], [b[i]], s=140, marker="*", color="red", zorder=7,
               label=f"lane change to the {side}, t = {change_s:.1f} s")
    ax.set_xlim(s0, s1)
    ax.set_ylim(b.min() - 9, b.max() + 9)
    ax.set_xlabel("metres along the ego's direction of travel")
    ax.set_ylabel("metres to its left")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"no match: {drive_id}, ego {ego_id}", fontsize=10)
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m logiq_sql.evaluation.real_sample", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--db", required=True)
    p.add_argument("--scenario", default="sut_cut_out")
    p.add_argument("--out", required=True)
    p.add_argument("--n", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    con = connect(args.db, read_only=True)
    try:
        matches, changes = candidates(con, args.scenario)
        rows = []
        for m in matches.sample(min(args.n, matches.height), seed=args.seed).iter_rows(named=True):
            name = f"match_{m['drive_id']}_{m['ego_id']}_{m['start_s']:.1f}.png"
            birds_eye(con, m["match_id"]).savefig(out / name, dpi=90)
            rows.append({"kind": "match", "file": name, "drive_id": m["drive_id"], "ego_id": m["ego_id"],
                         "actor_id": m["actor_id"], "t_s": m["start_s"], "verdict": ""})
        for c in changes.sample(min(args.n, changes.height), seed=args.seed).iter_rows(named=True):
            name = f"nomatch_{c['drive_id']}_{c['ego_id']}_{c['change_s']:.1f}.png"
            draw_change(con, c["drive_id"], c["ego_id"], c["change_s"], c["lane_change_side"]).savefig(
                out / name, dpi=90)
            rows.append({"kind": "no match", "file": name, "drive_id": c["drive_id"], "ego_id": c["ego_id"],
                         "actor_id": None, "t_s": c["change_s"], "verdict": ""})
    finally:
        con.close()
    pl.DataFrame(rows, schema={"kind": pl.String, "file": pl.String, "drive_id": pl.String, "ego_id": pl.String,
                               "actor_id": pl.String, "t_s": pl.Float64, "verdict": pl.String}
                 ).write_csv(out / "sample.csv")
    print(f"{out}: {matches.height} match(es), {changes.height} uncovered ego lane change(s); drew "
          f"{min(args.n, matches.height)} and {min(args.n, changes.height)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
