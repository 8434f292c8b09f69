"""Animated bird's-eye replays of matches: one scene model, drawn by the report's canvas and by matplotlib.

``scenes`` reads the tracks and the map of a set of matches (set-based SQL in ``queries/replay/``, the gap,
headway and TTC from ``queries/relations/relations.sql`` itself) and encodes each match as a compact dict:
positions quantised to ``QUANTUM_M`` and delta-coded, headings in centiradians, one list per actor. The report
embeds that dict as gzip + base64 and decodes it in the browser only when the match is opened (``REPLAY_JS``);
``animation`` decodes the very same dict with ``decode`` and draws it with matplotlib. ``LAYOUT`` and ``STYLE``
(panels, colours, what is faint) are read by both renderers, so the two pictures agree.
"""

from __future__ import annotations

import base64
import gzip
import json
from collections.abc import Iterable
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import shapely

from logiq_sql.db import connect
from logiq_sql.errors import InputError
from logiq_sql.plan import ALL_KINDS_CSV, DEFAULT_MIN_CLOSING_SPEED_MPS
from logiq_sql.plots import ACTOR_COLOUR, EGO_COLOUR, PHASE_COLOURS
from logiq_sql.sql import bind, query_text

MARGIN_S = 1.0  # shown before and after the match
OTHERS_RANGE_M = 60.0  # other road users within this distance of the ego are drawn (faint)
QUANTUM_M = 0.1  # positions and box sizes are stored in decimetres
VIEW_MIN_M, VIEW_MAX_M = 18.0, 60.0  # half-width of the view that follows the ego
ANY_RANGE_M = 1e9  # the pairs are chosen already: relations.sql must not drop any by distance
BATCH = 400  # matches read per query: bounds memory for files with thousands of matches

# the values plotted under the map: (column, label, scale of the stored integers)
SERIES = (("lon_gap_m", "gap (m)", 0.1), ("time_headway_s", "headway (s)", 0.1), ("ttc_s", "TTC (s)", 0.1),
          ("ego_speed_mps", "ego speed (m/s)", 0.1), ("actor_speed_mps", "actor speed (m/s)", 0.1))
# chart panels: title, the series sharing it, the top of its axis at most (a headway of a crawling car runs to
# hundreds of seconds; values above are drawn at the top edge)
PANELS = (("gap (m)", ("lon_gap_m",), None), ("headway and TTC (s)", ("time_headway_s", "ttc_s"), 10.0),
          ("speed (m/s)", ("ego_speed_mps", "actor_speed_mps"), None))
SERIES_COLOURS = {"lon_gap_m": "#2c7fb8", "time_headway_s": "#7fcdbb", "ttc_s": "#d95f0e",
                  "ego_speed_mps": EGO_COLOUR, "actor_speed_mps": ACTOR_COLOUR}
STYLE = {
    "ego": EGO_COLOUR, "actor": ACTOR_COLOUR, "other": "#6b6b6b", "other_alpha": 0.3,
    "lane_fill": "#e6e6e6", "lane_edge": "#a0a0a0", "junction_fill": "#f5c16c", "junction_edge": "#b07d1a",
    "junction_alpha": 0.4, "background": "#fbfbf8", "phases": list(PHASE_COLOURS), "series": SERIES_COLOURS,
}
# map 4:3 on the left, phase timeline under it, one chart per panel on the right (fractions of the figure)
LAYOUT = {"width": 980, "height": 520, "map": [0.0, 0.0, 0.62, 0.86], "timeline": [0.0, 0.88, 0.62, 0.12],
          "charts": [0.65, 0.0, 0.35, 1.0]}

# relations.sql reads these tables; the replay gives it only the rows of the replayed pairs and no lane relations
# (same_lane and adjacent_side are not shown), so gap, headway and TTC are those matching computed
RELATION_INPUTS = {
    "tracks": "select * from pair_tracks",
    "ego_lanes": ("select distinct t.drive_id, t.actor_id as ego_id, t.frame, cast(null as varchar) as lane_id, "
                  "cast(null as bigint) as lane_run, t.drive_key, t.actor_key as ego_key "
                  "from pair_tracks as t inner join replay_windows as w on t.drive_id = w.drive_id "
                  "and t.actor_id = w.ego_id"),
    "actor_lanes": ("select drive_key, actor_key, drive_id, actor_id, frame, cast(null as varchar) as lane_id, "
                    "cast(null as double) as lane_dist_m from pair_tracks where false"),
    "lane_neighbours": ("select cast(null as varchar) as map_id, cast(null as varchar) as lane_id, "
                        "cast(null as varchar) as near_lane_id, cast(null as varchar) as side where false"),
    "lane_line": ("select cast(null as varchar) as map_id, cast(null as varchar) as lane_id, "
                  "cast(null as varchar) as line_lane_id where false"),
}
REPLAY_JS = (Path(__file__).parent / "replay.js").read_text(encoding="utf-8")


# the replay's query files in the order they run, each becoming the table named first (lint checks them on Spark;
# pair_relations is relations.sql over the RELATION_INPUTS stand-ins), and their parameters
STEPS = (("replay_windows", "replay/windows.sql"), ("pair_tracks", "replay/pair_tracks.sql"),
         ("pair_relations", "relations/relations.sql"), ("replay_frames", "replay/match_frames.sql"),
         ("replay_others", "replay/others.sql"))
PARAMS = {"margin_s": MARGIN_S, "others_range_m": OTHERS_RANGE_M, "relation_range_m": ANY_RANGE_M,
          "object_relation_range_m": ANY_RANGE_M, "relation_kinds_csv": ALL_KINDS_CSV,
          # TTC and MTTC as the vehicle scenarios' default min_closing_speed makes them (NULL below it)
          "min_closing_speed_mps": DEFAULT_MIN_CLOSING_SPEED_MPS}


def _relations_sql() -> str:
    ctes = ",\n".join(f"{name} as ({sql})" for name, sql in RELATION_INPUTS.items())
    return f"with {ctes}\nselect * from (\n{query_text('relations/relations.sql')}\n)"


def _delta(column: str, by: str = "match_id") -> pl.Expr:
    """Quantised integers of ``column`` as differences to the previous non-null value (the first one as is);
    NULL stays NULL. ``_undelta`` inverts it."""
    value = pl.col(column)
    filled = value.forward_fill().over(by)
    step = (filled - filled.shift(1).over(by)).fill_null(filled)
    return pl.when(value.is_null()).then(None).otherwise(step).alias(column)


def _undelta(values: list) -> np.ndarray:
    steps = np.array(values, dtype=float)  # None -> NaN
    out = np.cumsum(np.nan_to_num(steps))
    out[np.isnan(steps)] = np.nan
    return out


def _q(expr: pl.Expr, scale: float) -> pl.Expr:
    return (expr / scale).round().cast(pl.Int32)


def _frames(con: duckdb.DuckDBPyConnection, ids: list[str]) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    con.execute("create or replace temp table replay_ids as select unnest($ids) as match_id", {"ids": ids})
    con.execute("create or replace temp table replay_windows as " + query_text("replay/windows.sql"),
                bind("replay/windows.sql", PARAMS))
    con.execute("create or replace temp table pair_tracks as " + query_text("replay/pair_tracks.sql"))
    con.execute("create or replace temp table pair_relations as " + _relations_sql(),
                bind("relations/relations.sql", PARAMS))
    windows = con.sql("select * from replay_windows").pl()
    frames = con.sql(query_text("replay/match_frames.sql")).pl()
    others = con.sql(query_text("replay/others.sql"),
                     params=bind("replay/others.sql", PARAMS)).pl()
    return windows, frames, others


def _encode(windows: pl.DataFrame, frames: pl.DataFrame, others: pl.DataFrame, phases: pl.DataFrame,
            pet: dict[str, float | None]) -> list[dict]:
    """One compact scene dict per match (vectorised per column; the loop is over matches)."""
    frames = frames.with_columns(pl.int_range(pl.len()).over("match_id").alias("i"),
                                 pl.col("ego_x_m").first().over("match_id").round().alias("ox"),
                                 pl.col("ego_y_m").first().over("match_id").round().alias("oy"))
    origin = frames.group_by("match_id").agg(pl.col("ox", "oy").first(), pl.col("t_s").first().alias("t0"))
    # the view: wide enough for the actor most of the time, never a thin strip
    dist = ((pl.col("actor_x_m") - pl.col("ego_x_m")) ** 2 + (pl.col("actor_y_m") - pl.col("ego_y_m")) ** 2).sqrt()
    view = frames.group_by("match_id").agg((dist.quantile(0.8) + 10).fill_null(VIEW_MIN_M)
                                           .clip(VIEW_MIN_M, VIEW_MAX_M).alias("view_m"))
    q = QUANTUM_M
    coded = frames.with_columns(
        _q(pl.col("ego_x_m") - pl.col("ox"), q).alias("ex"), _q(pl.col("ego_y_m") - pl.col("oy"), q).alias("ey"),
        _q(pl.col("actor_x_m") - pl.col("ox"), q).alias("ax"), _q(pl.col("actor_y_m") - pl.col("oy"), q).alias("ay"),
        _q(pl.col("ego_heading_rad"), 0.01).alias("eh"), _q(pl.col("actor_heading_rad"), 0.01).alias("ah"),
        *[_q(pl.col(c), s).alias(c) for c, _, s in SERIES],
    ).with_columns(*[_delta(c) for c in ("frame", "ex", "ey", "ax", "ay", "eh", "ah")])
    per_match = coded.group_by("match_id", maintain_order=True).agg(
        "frame", "ex", "ey", "eh", "ax", "ay", "ah", *[c for c, _, _ in SERIES],
        _q(pl.col("ego_length_m").median(), q).alias("el"), _q(pl.col("ego_width_m").median(), q).alias("ew"),
        _q(pl.col("actor_length_m").median(), q).alias("al"), _q(pl.col("actor_width_m").median(), q).alias("aw"))
    index = frames.select("match_id", "frame", "i", "ox", "oy")
    other = (others.join(index, on=["match_id", "frame"]).sort("match_id", "actor_id", "frame")
             .with_columns(_q(pl.col("x_m") - pl.col("ox"), q).alias("x"),
                           _q(pl.col("y_m") - pl.col("oy"), q).alias("y"), _q(pl.col("heading_rad"), 0.01).alias("h"),
                           pl.concat_str("match_id", "actor_id").alias("key"))
             .with_columns(*[_delta(c, "key") for c in ("i", "x", "y", "h")])
             .group_by("match_id", "actor_id", maintain_order=True)
             .agg(pl.col("kind").first().alias("k"), "i", "x", "y", "h",
                  _q(pl.col("length_m").median(), q).alias("l"), _q(pl.col("width_m").median(), q).alias("w"))
             .group_by("match_id", maintain_order=True).agg(pl.struct("k", "i", "x", "y", "h", "l", "w").alias("o")))
    phase_rows = (phases.join(index.select("match_id", "frame", "i"), left_on=["match_id", "start_frame"],
                              right_on=["match_id", "frame"], how="left")
                  .join(index.select("match_id", "frame", pl.col("i").alias("j")), left_on=["match_id", "end_frame"],
                        right_on=["match_id", "frame"], how="left")
                  .sort("match_id", "phase_index")
                  .group_by("match_id", maintain_order=True)
                  .agg(pl.concat_list(pl.col("phase_index").cast(pl.Int64).cast(pl.String), "phase",
                                      pl.col("i").cast(pl.String), pl.col("j").cast(pl.String)).alias("p")))
    table = (windows.join(per_match, on="match_id").join(origin, on="match_id").join(view, on="match_id")
             .join(other, on="match_id", how="left").join(phase_rows, on="match_id", how="left"))
    out = []
    for r in table.iter_rows(named=True):  # one dict per match, from lists already built
        out.append({
            "id": r["match_id"], "scenario": r["scenario"], "drive": r["drive_id"], "map": r["map_id"],
            "ego": r["ego_id"], "actor": r["actor_id"], "start_s": r["start_s"], "end_s": r["end_s"],
            "t0": r["t0"], "dt": r["dt_s"], "origin": [r["ox"], r["oy"]], "q": QUANTUM_M,
            "view_m": round(r["view_m"], 1),
            "pet_s": pet.get(r["match_id"]),
            "f": r["frame"],
            "e": {"x": r["ex"], "y": r["ey"], "h": r["eh"], "l": r["el"], "w": r["ew"]},
            "a": {"x": r["ax"], "y": r["ay"], "h": r["ah"], "l": r["al"], "w": r["aw"]},
            "o": r["o"] or [],
            "s": {c: r[c] for c, _, _ in SERIES},
            "p": [[int(i), name, None if a is None else int(a), None if b is None else int(b)]
                  for i, name, a, b in (r["p"] or [])],
        })
    return out


def _rings(wkt: list[str], box: shapely.Geometry, origin: tuple[float, float]) -> list[list[int]]:
    """Exterior rings of the polygons touching ``box``, simplified below the quantum, as delta-coded integers."""
    if not wkt:
        return []
    geoms = shapely.from_wkt(np.asarray(wkt, dtype=object))
    geoms = geoms[shapely.intersects(geoms, box)]
    parts = shapely.get_parts(shapely.simplify(geoms, QUANTUM_M / 2))
    rings = shapely.get_exterior_ring(parts[shapely.get_type_id(parts) == 3])
    out = []
    for ring in rings:
        xy = np.rint((shapely.get_coordinates(ring) - origin) / QUANTUM_M).astype(np.int64)
        out.append(np.diff(xy, axis=0, prepend=0).ravel().tolist())
    return out


def _maps(con: duckdb.DuckDBPyConnection, encoded: list[dict]) -> dict[str, dict]:
    """Per map: the lanes and junctions within view of any replayed match (shared by the matches on that map)."""
    boxes: dict[str, list] = {}
    for s in encoded:
        if s["map"] is None:
            continue
        x, y = _undelta(s["e"]["x"]) * QUANTUM_M + s["origin"][0], _undelta(s["e"]["y"]) * QUANTUM_M + s["origin"][1]
        r = s["view_m"] * 1.5
        boxes.setdefault(s["map"], []).append(shapely.box(np.nanmin(x) - r, np.nanmin(y) - r, np.nanmax(x) + r,
                                                          np.nanmax(y) + r))
    out = {}
    for map_id, parts in boxes.items():
        area = shapely.union_all(parts)
        origin = (round(area.bounds[0]), round(area.bounds[1]))
        lanes = con.sql("select polygon_wkt from lanes where map_id = $m and polygon_wkt is not null",
                        params={"m": map_id}).pl()["polygon_wkt"].to_list()
        junctions = con.sql("select polygon_wkt from junctions where map_id = $m and polygon_wkt is not null",
                            params={"m": map_id}).pl()["polygon_wkt"].to_list()
        out[map_id] = {"origin": list(origin), "q": QUANTUM_M, "lanes": _rings(lanes, area, origin),
                       "junctions": _rings(junctions, area, origin)}
    return out


def scenes(con: duckdb.DuckDBPyConnection, match_ids: Iterable[str]) -> tuple[list[dict], dict[str, dict]]:
    """The encoded scene of every match in ``match_ids`` (in that order) and the map parts they need, by map_id."""
    ids = list(dict.fromkeys(match_ids))
    encoded: list[dict] = []
    pet_column = "pet_between_sut_and_npc_s" in con.sql("select * from kpis limit 0").columns
    for start in range(0, len(ids), BATCH):
        batch = ids[start:start + BATCH]
        windows, frames, others = _frames(con, batch)
        phases = con.sql("select match_id, phase_index, phase, start_frame, end_frame from match_phases "
                         "where match_id in (select match_id from replay_ids)").pl()
        pet = dict(con.execute("select match_id, pet_between_sut_and_npc_s from kpis where match_id in "
                               "(select match_id from replay_ids)").fetchall()) if pet_column else {}
        encoded += _encode(windows, frames, others, phases, pet)
    order = {m: i for i, m in enumerate(ids)}
    encoded.sort(key=lambda s: order[s["id"]])
    return encoded, _maps(con, encoded)


def scene(db: str | Path | duckdb.DuckDBPyConnection, match_id: str) -> dict:
    """The encoded scene of one match, its map part inline under ``"lanes"``."""
    con = db if isinstance(db, duckdb.DuckDBPyConnection) else _open(db)
    try:
        (found, maps) = scenes(con, [match_id])
    finally:
        if con is not db:
            con.close()
    if not found:
        raise InputError(f"match_id {match_id}: no such match in {db} (list them with "
                         "`logiq-sql query --db FILE \"select match_id, scenario from matches\"`).")
    s = found[0]
    s["lanes"] = maps.get(s["map"])
    return s


def _open(db: str | Path) -> duckdb.DuckDBPyConnection:
    if not Path(db).is_file():
        raise InputError(f"--db {db}: no such file (write one with `logiq-sql ingest` and `logiq-sql match`).")
    return connect(db, read_only=True)


def pack(value: dict) -> str:
    """gzip + base64 of compact JSON: how the report embeds a scene (decoded in the browser on demand)."""
    text = json.dumps(value, separators=(",", ":"), allow_nan=False)
    return base64.b64encode(gzip.compress(text.encode(), mtime=0)).decode()


# ---- decoding (Python side; REPLAY_JS does the same in the browser) ----

def decode(s: dict) -> dict:
    """Metric arrays of an encoded scene: t_s, ego/actor x, y, heading per frame, others, series, lanes."""
    q = s["q"]
    ox, oy = s["origin"]
    frames = _undelta(s["f"])

    def actor(a: dict) -> dict:
        return {"x": _undelta(a["x"]) * q + ox, "y": _undelta(a["y"]) * q + oy, "h": _undelta(a["h"]) * 0.01,
                "l": (a["l"] or 0) * q, "w": (a["w"] or 0) * q}

    n = len(frames)
    others = []
    for o in s["o"]:
        x, y, h = (np.full(n, np.nan) for _ in range(3))
        idx = _undelta(o["i"]).astype(int)
        x[idx], y[idx], h[idx] = _undelta(o["x"]) * q + ox, _undelta(o["y"]) * q + oy, _undelta(o["h"]) * 0.01
        others.append({"x": x, "y": y, "h": h, "l": o["l"] * q, "w": o["w"] * q, "kind": o["k"]})
    scale = {c: k for c, _, k in SERIES}
    series = {c: np.array(vals, dtype=float) * scale[c] for c, vals in s["s"].items()}
    lanes, junctions = [], []
    if s.get("lanes"):
        m = s["lanes"]
        for key, into in (("lanes", lanes), ("junctions", junctions)):
            for ring in m[key]:
                xy = np.cumsum(np.asarray(ring, dtype=float).reshape(-1, 2), axis=0) * m["q"] + m["origin"]
                into.append(xy)
    return {"t_s": s["t0"] + (frames - frames[0]) * s["dt"], "ego": actor(s["e"]), "actor": actor(s["a"]),
            "others": others, "series": series, "phases": s["p"], "lanes": lanes, "junctions": junctions}


def box_corners(x: float, y: float, h: float, length: float, width: float) -> np.ndarray:
    """The four corners of a box centred on (x, y) with heading h: front left, front right, rear right, rear left."""
    c, s = np.cos(h), np.sin(h)
    along = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return np.column_stack([x + along[:, 0] * c - along[:, 1] * s, y + along[:, 0] * s + along[:, 1] * c])


# ---- matplotlib (notebooks, GIF and MP4): the same scene, layout and colours as REPLAY_JS ----

def _axes_rect(part: list[float], pad: tuple[float, float, float, float] = (0, 0, 0, 0)) -> list[float]:
    """A LAYOUT part (x, y from the top, w, h; fractions) as matplotlib's (left, bottom, w, h), padded inwards."""
    x, y, w, h = part
    left, top, right, bottom = pad
    return [x + left, 1 - y - h + bottom, w - left - right, h - top - bottom]


MAX_FRAMES = 150  # a replay longer than this skips frames evenly (GIF size, notebook size)


def _step(n: int, max_frames: int) -> int:
    return max(1, -(-n // max_frames))


def animation(db: str | Path | duckdb.DuckDBPyConnection | dict, match_id: str | None = None, step: int | None = None,
              max_frames: int = MAX_FRAMES):
    """A ``matplotlib.animation.FuncAnimation`` of one match (in a notebook: ``HTML(anim.to_jshtml())``).

    ``db`` is a DuckDB file or connection (with ``match_id``) or a scene from ``scene``. Every ``step``-th frame
    is drawn; by default at most ``max_frames`` frames, at the recorded speed.
    """
    from matplotlib.animation import FuncAnimation
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    s = db if isinstance(db, dict) else scene(db, match_id)
    d = decode(s)
    n = len(d["t_s"])
    step = step or _step(n, max_frames)
    fig = Figure(figsize=(LAYOUT["width"] / 100, LAYOUT["height"] / 100), dpi=100, facecolor="white")
    fig.suptitle(f"{s['scenario']}: drive {s['drive']}, ego {s['ego']} (blue), actor {s['actor']} (red), "
                 f"match {s['start_s']:.1f} to {s['end_s']:.1f} s", fontsize=8, x=0.01, ha="left", y=0.995)
    ax = fig.add_axes(_axes_rect(LAYOUT["map"], (0.04, 0.05, 0.0, 0.03)))
    ax.set_facecolor(STYLE["background"])
    ax.set_aspect("equal", adjustable="box")
    ax.tick_params(labelsize=6)
    ax.add_collection(PolyCollection(d["lanes"], facecolor=STYLE["lane_fill"], edgecolor=STYLE["lane_edge"],
                                     linewidth=0.6, zorder=1))
    ax.add_collection(PolyCollection(d["junctions"], facecolor=STYLE["junction_fill"],
                                     edgecolor=STYLE["junction_edge"], alpha=STYLE["junction_alpha"], zorder=2))
    others = PolyCollection([], facecolor=STYLE["other"], edgecolor="black", alpha=STYLE["other_alpha"], zorder=3)
    ax.add_collection(others)
    trails = {k: ax.plot([], [], color=STYLE[k], alpha=0.5, linewidth=1.5, zorder=4)[0] for k in ("ego", "actor")}
    boxes = {k: ax.add_patch(Polygon(np.zeros((4, 2)), closed=True, facecolor=STYLE[k], edgecolor="black",
                                     zorder=5)) for k in ("ego", "actor")}
    noses = {k: ax.plot([], [], color="white", linewidth=1.5, zorder=6)[0] for k in ("ego", "actor")}
    half_w = s["view_m"]
    map_w, map_h = LAYOUT["map"][2] * LAYOUT["width"], LAYOUT["map"][3] * LAYOUT["height"]
    half_h = half_w * map_h / map_w

    tl = fig.add_axes(_axes_rect(LAYOUT["timeline"], (0.04, 0.02, 0.0, 0.04)))
    tl.set_xlim(0, max(n - 1, 1))
    tl.set_yticks([])
    tl.tick_params(labelsize=6)
    for index, name, a, b in d["phases"]:
        a, b = (0 if a is None else a), (n - 1 if b is None else b)
        tl.broken_barh([(a, max(b - a, 0.5))], (0, 1), color=STYLE["phases"][(index - 1) % len(STYLE["phases"])])
        tl.text(a + 0.5, 0.5, f"{index}. {name}", color="white", fontsize=6, va="center", clip_on=True)
    cursors = [tl.axvline(0, color="black", linewidth=2)]

    values = []
    label = {c: name for c, name, _ in SERIES}
    rows = len(PANELS)
    for k, (title, columns, cap) in enumerate(PANELS):
        x, y, w, h = LAYOUT["charts"]
        part = [x, y + k * h / rows, w, h / rows]
        cax = fig.add_axes(_axes_rect(part, (0.02, 0.05, 0.01, 0.03)))
        cax.tick_params(labelsize=6)
        cax.set_xlim(0, max(n - 1, 1))
        if "TTC" in title and s.get("pet_s") is not None:
            title += f", PET {s['pet_s']:.2f} s"
        cax.set_title(title, fontsize=7, loc="left")
        for j, c in enumerate(columns):
            series = d["series"][c]
            cax.plot(np.arange(n), np.minimum(series, cap) if cap else series, color=STYLE["series"][c],
                     linewidth=1.2)
            values.append((cax.text(0.02 + j * 0.5, 0.85, "", transform=cax.transAxes, fontsize=6,
                                    color=STYLE["series"][c]), series, label[c]))
        shown = np.concatenate([d["series"][c] for c in columns])
        shown = shown[np.isfinite(shown)]
        top = max(1.0, float(shown.max()) if shown.size else 1.0)
        cax.set_ylim(min(0.0, float(shown.min()) if shown.size else 0.0), min(top, cap) if cap else top * 1.05)
        cursors.append(cax.axvline(0, color="black", linewidth=1))

    def draw(i: int):
        ex, ey = d["ego"]["x"][i], d["ego"]["y"][i]
        ax.set_xlim(ex - half_w, ex + half_w)
        ax.set_ylim(ey - half_h, ey + half_h)
        polys = [box_corners(o["x"][i], o["y"][i], o["h"][i], o["l"], o["w"]) for o in d["others"]
                 if not np.isnan(o["x"][i])]
        others.set_verts(polys)
        for k in ("ego", "actor"):
            a = d[k]
            trails[k].set_data(a["x"][:i + 1], a["y"][:i + 1])
            visible = not np.isnan(a["x"][i])
            boxes[k].set_visible(visible)
            noses[k].set_visible(visible)
            if visible:
                boxes[k].set_xy(box_corners(a["x"][i], a["y"][i], a["h"][i], a["l"], a["w"]))
                noses[k].set_data([a["x"][i], a["x"][i] + a["l"] / 2 * np.cos(a["h"][i])],
                                  [a["y"][i], a["y"][i] + a["l"] / 2 * np.sin(a["h"][i])])
        for cursor in cursors:
            cursor.set_xdata([i, i])
        for text, series, name in values:
            text.set_text(f"{name} {'n/a' if np.isnan(series[i]) else f'{series[i]:.1f}'}")
        return []

    draw(0)
    return FuncAnimation(fig, draw, frames=range(0, n, step), interval=1000 * s["dt"] * step, blit=False)


def save(db: str | Path, match_id: str, out: str | Path, step: int | None = None) -> Path:
    """Write the replay of one match as a GIF (Pillow) or an MP4 (ffmpeg from imageio-ffmpeg)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InputError(f"--out {out}: write a .gif or an .mp4 file.")
    s = scene(db, match_id)
    step = step or _step(len(s["f"]), MAX_FRAMES)
    anim = animation(s, step=step)
    fps = max(1, round(1 / (s["dt"] * step)))
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".gif":
        from matplotlib.animation import PillowWriter
        anim.save(out, writer=PillowWriter(fps=fps))
    else:
        import imageio_ffmpeg
        from matplotlib import rcParams
        from matplotlib.animation import FFMpegWriter
        rcParams["animation.ffmpeg_path"] = imageio_ffmpeg.get_ffmpeg_exe()
        anim.save(out, writer=FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"]))
    return out
