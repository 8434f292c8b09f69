"""Pictures of matches and coverage (matplotlib), shared by the notebooks and the HTML report.

Each function takes the frames a run returns (or the DuckDB file) and returns a ``matplotlib.figure.Figure``
built without pyplot, so it works in a notebook, in a headless report run and in tests alike.
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import shapely
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from logiq_sql.storage.db import open_current

# phases: a qualitative palette clear of the ego's blue, the actor's red, the grey of other road users, the tan of
# junctions and the replay's measure colours (replay.SERIES_COLOURS)
PHASE_COLOURS = ("#1b9e77", "#e7298a", "#66a61e", "#17becf", "#bcbd22", "#8c564b")
EGO_COLOUR, ACTOR_COLOUR, EMPTY_COLOUR = "#1f4e9c", "#c0392b", "#d62728"
SPECIAL_BUCKETS = ("out_of_range", "missing")  # coverage rows that are not buckets of the item


def phase_colour(index: int) -> str:
    return PHASE_COLOURS[(index - 1) % len(PHASE_COLOURS)]


def match_timeline(matches: pl.DataFrame, match_phases: pl.DataFrame, limit: int = 25) -> Figure:
    """One row per match (the first ``limit`` by drive and start), its phases as coloured bars over time.

    Times are relative to each match's start, so matches of different drives line up.
    """
    shown = matches.sort("drive_id", "start_s", "ego_id", "actor_id").head(limit).with_row_index("row")
    bars = match_phases.join(shown.select("match_id", "row", pl.col("start_s").alias("match_start_s")),
                             on="match_id").with_columns(
        (pl.col("start_s") - pl.col("match_start_s")).alias("from_s"),
        # a one-frame phase has start = end: give it a visible width
        pl.max_horizontal(pl.col("end_s") - pl.col("start_s"), pl.lit(0.1)).alias("width_s"))
    fig = Figure(figsize=(9, 0.8 + 0.3 * max(shown.height, 1)), layout="constrained")
    ax = fig.add_subplot()
    names = bars.select("phase_index", "phase").unique().sort("phase_index")
    for index, phase in names.iter_rows():
        part = bars.filter(pl.col("phase_index") == index)
        ax.barh(part["row"].to_numpy(), part["width_s"].to_numpy(), left=part["from_s"].to_numpy(), height=0.7,
                color=phase_colour(index), label=f"{index}. {phase}")
    ax.set_yticks(shown["row"].to_numpy(),
                  [f"{d[:18]} ego {e} / {a}" for d, e, a in shown.select("drive_id", "ego_id", "actor_id").rows()],
                  fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("seconds since the start of the match")
    title = ", ".join(shown["scenario"].unique(maintain_order=True).to_list())
    ax.set_title(f"{title}: phases of {shown.height} of {matches.height} match(es)", fontsize=10)
    if names.height:
        ax.legend(loc="lower right", fontsize=7)
    return fig


def _match_geometry(con: duckdb.DuckDBPyConnection, match_id: str, margin_s: float):
    match = con.sql("select m.*, d.map_id from matches m join drive_inputs d using (drive_id) where match_id = $id",
                    params={"id": match_id}).pl()
    if match.is_empty():
        raise KeyError(f"match_id {match_id}: no such match in the file.")
    m = match.row(0, named=True)
    params = {"d": m["drive_id"], "e": m["ego_id"], "a": m["actor_id"],
              "t0": m["start_s"] - margin_s, "t1": m["end_s"] + margin_s}
    paths = con.sql("select actor_id, t_s, x_m, y_m from tracks where drive_id = $d and actor_id in ($e, $a) "
                    "and t_s between $t0 and $t1 order by actor_id, t_s", params=params).pl()
    phases = con.sql("select p.phase_index, p.phase, p.start_s, t.actor_id, t.x_m, t.y_m from match_phases p "
                     "join tracks t on t.drive_id = $d and t.actor_id in ($e, $a) and t.frame = p.start_frame "
                     "where p.match_id = $id order by p.phase_index",
                     params={"id": match_id, "d": m["drive_id"], "e": m["ego_id"], "a": m["actor_id"]}).pl()
    lanes = con.sql("select polygon_wkt, junction_id from lanes where map_id = $map",
                    params={"map": m["map_id"]}).pl()
    junctions = con.sql("select polygon_wkt from junctions where map_id = $map", params={"map": m["map_id"]}).pl()
    return m, paths, phases, lanes, junctions


def _polygons(wkt: pl.Series, box: shapely.Geometry) -> list[np.ndarray]:
    """Exterior rings of the polygons that touch ``box``, clipped to it."""
    geoms = shapely.from_wkt(wkt.to_numpy())
    clipped = shapely.intersection(geoms[shapely.intersects(geoms, box)], box)
    parts = shapely.get_parts(clipped)
    rings = shapely.get_exterior_ring(parts[shapely.get_type_id(parts) == 3])
    return [shapely.get_coordinates(r) for r in rings]


def birds_eye(db: str | Path | duckdb.DuckDBPyConnection, match_id: str, margin_s: float = 1.0,
              margin_m: float = 25.0) -> Figure:
    """The ego's and the actor's paths during a match (plus ``margin_s`` either side) over the map's lanes and
    junctions, with both positions marked where each phase starts."""
    con = db if isinstance(db, duckdb.DuckDBPyConnection) else open_current(db)
    try:
        m, paths, phases, lanes, junctions = _match_geometry(con, match_id, margin_s)
    finally:
        if con is not db:
            con.close()
    x, y = paths["x_m"], paths["y_m"]
    box = shapely.box(x.min() - margin_m, y.min() - margin_m, x.max() + margin_m, y.max() + margin_m)
    fig = Figure(figsize=(7, 7), layout="constrained")
    ax = fig.add_subplot()
    if not lanes.is_empty():
        ax.add_collection(PolyCollection(_polygons(lanes["polygon_wkt"], box), facecolor="#e8e8e8",
                                         edgecolor="#9a9a9a", linewidth=0.5, zorder=1))
    if not junctions.is_empty():
        ax.add_collection(PolyCollection(_polygons(junctions["polygon_wkt"], box), facecolor="#f5c16c",
                                         edgecolor="#b07d1a", alpha=0.45, linewidth=1.0, zorder=2))
    for actor, colour, role in ((m["ego_id"], EGO_COLOUR, "ego (SUT)"), (m["actor_id"], ACTOR_COLOUR, "actor")):
        path = paths.filter(pl.col("actor_id") == actor)
        during = path.filter(pl.col("t_s").is_between(m["start_s"], m["end_s"]))
        ax.plot(path["x_m"], path["y_m"], color=colour, linewidth=1, alpha=0.4, zorder=3)
        ax.plot(during["x_m"], during["y_m"], color=colour, linewidth=2.5, zorder=4, label=f"{role} {actor}")
        if during.height > 1:  # an arrow at the end shows the direction of travel
            ax.annotate("", xy=(during["x_m"][-1], during["y_m"][-1]), xytext=(during["x_m"][-2], during["y_m"][-2]),
                        arrowprops={"arrowstyle": "-|>", "color": colour}, zorder=5)
    for index, phase, start_s in phases.select("phase_index", "phase", "start_s").unique(maintain_order=True).rows():
        at = phases.filter(pl.col("phase_index") == index)
        ax.scatter(at["x_m"], at["y_m"], s=45, color=phase_colour(index), edgecolor="black", zorder=6,
                   label=f"{index}. {phase} starts, t = {start_s:.1f} s")
    ax.set_xlim(box.bounds[0], box.bounds[2])
    ax.set_ylim(box.bounds[1], box.bounds[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    handles, labels = ax.get_legend_handles_labels()
    if not junctions.is_empty():
        handles.append(Patch(facecolor="#f5c16c", edgecolor="#b07d1a", alpha=0.45))
        labels.append("junction")
    # below the map, never over the cars
    fig.legend(handles, labels, fontsize=7, loc="outside lower center", ncols=2)
    ax.set_title(f"{m['scenario']}\n{m['drive_id']}, {m['start_s']:.1f}-{m['end_s']:.1f} s", fontsize=10)
    return fig


def _wrapped(name: str, width: int = 34) -> str:
    """A snake_case name broken at underscores into lines of at most ``width`` characters (titles that fit their
    panel instead of running into the next one)."""
    lines = [""]
    for part in name.split("_"):
        piece = part if not lines[-1] else "_" + part
        if lines[-1] and len(lines[-1]) + len(piece) > width:
            lines.append("_" + part)
        else:
            lines[-1] += piece
    return "\n".join(lines)


def coverage_histogram(coverage: pl.DataFrame, scenario: str, item: str, ax: Axes, unit: str | None = None) -> None:
    """Hits per bucket of one coverage item, empty buckets marked in red, out_of_range / missing at the end; a
    numeric item's buckets and axis carry its ``unit``."""
    rows = coverage.filter((pl.col("scenario") == scenario) & (pl.col("item") == item)).with_columns(
        pl.col("bucket").is_in(SPECIAL_BUCKETS).alias("special")).sort("special", "bucket_index", nulls_last=True)
    # out_of_range and missing only when they hold samples: they are not buckets to fill
    rows = rows.filter(~pl.col("special") | (pl.col("hits") > 0))
    pos = np.arange(rows.height)
    hits = rows["hits"].to_numpy()
    empty = hits == 0
    ax.bar(pos, hits, color=np.where(rows["special"].to_numpy(), "#9a9a9a", "#4c72b0"))
    top = max(int(hits.max()) if hits.size else 0, 1)
    for p in pos[empty]:
        ax.axvspan(p - 0.45, p + 0.45, color=EMPTY_COLOUR, alpha=0.12, linewidth=0)
        ax.text(p, top * 0.02, "0", color=EMPTY_COLOUR, ha="center", va="bottom", fontsize=7)
    ax.set_ylim(0, top * 1.1)
    numeric = rows["lo"].is_not_null().to_numpy()
    labels = [f"{b} {unit}" if unit and n else b for b, n in zip(rows["bucket"], numeric, strict=True)]
    ax.set_xticks(pos, labels, rotation=90, ha="center", fontsize=6)  # upright boxes: checkably apart
    ax.set_xlabel(f"value ({unit})" if unit and numeric.any() else "value", fontsize=7)
    ax.set_ylabel("matches", fontsize=7)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts: no 2.5 matches
    buckets = ~rows["special"].to_numpy()
    ax.set_title(f"{_wrapped(item)}\n{int((empty & buckets).sum())} of {int(buckets.sum())} buckets empty", fontsize=7)
    ax.tick_params(axis="y", labelsize=7)


def coverage_grid(coverage: pl.DataFrame, scenario: str, columns: int = 3,
                  units: dict[str, str] | None = None) -> Figure:
    """Every coverage item of a scenario, one histogram each; ``units`` maps an item to its unit."""
    items = coverage.filter(pl.col("scenario") == scenario)["item"].unique().sort().to_list()
    n_rows = max(-(-len(items) // columns), 1)
    fig = Figure(figsize=(3.4 * columns, 3.2 * n_rows), layout="constrained")
    axes = fig.subplots(n_rows, columns, squeeze=False).ravel()
    for item, ax in zip(items, axes, strict=False):
        coverage_histogram(coverage, scenario, item, ax, (units or {}).get(item))
    for ax in axes[len(items):]:
        ax.set_visible(False)
    fig.suptitle(f"coverage of {scenario} (red: empty buckets)", fontsize=10)
    return fig


def kpi_columns(kpis: pl.DataFrame, scenario: str) -> list[str]:
    """The numeric KPI columns that hold at least one value for the scenario."""
    rows = kpis.filter(pl.col("scenario") == scenario)
    return [c for c, t in rows.schema.items() if t.is_numeric() and rows[c].drop_nulls().drop_nans().len() > 0]


def kpi_grid(kpis: pl.DataFrame, scenario: str, columns: int = 4, units: dict[str, str] | None = None) -> Figure:
    """The distribution of every numeric KPI of a scenario over its matches; ``units`` maps a column to its unit
    (the x axis label)."""
    rows = kpis.filter(pl.col("scenario") == scenario)
    names = kpi_columns(kpis, scenario)
    n_rows = max(-(-len(names) // columns), 1)
    fig = Figure(figsize=(2.8 * columns, 2.4 * n_rows), layout="constrained")
    axes = fig.subplots(n_rows, columns, squeeze=False).ravel()
    for name, ax in zip(names, axes, strict=False):
        values = rows[name].drop_nulls().drop_nans().to_numpy()
        ax.hist(values, bins=min(20, max(len(np.unique(values)), 1)), color="#55a868")
        ax.set_title(f"{_wrapped(name, 30)}\n(n = {len(values)})", fontsize=7)
        ax.set_xlabel((units or {}).get(name, "value"), fontsize=7)
        ax.set_ylabel("matches", fontsize=7)
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=6)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    fig.suptitle(f"KPIs of {scenario} over {rows.height} match(es)", fontsize=10)
    return fig
