"""Animated bird's-eye replays of matches: one scene model, drawn by the report's canvas and by matplotlib.

``scenes`` reads the tracks and the map of a set of matches (set-based SQL in ``queries/replay/``, the gap,
headway and TTC from ``queries/relations/relations.sql`` itself) and encodes each match as a compact dict:
positions quantised to ``QUANTUM_M`` and delta-coded, headings in centiradians, one list per actor. The report
embeds that dict as gzip + base64 and decodes it in the browser only when the match is opened (``REPLAY_JS``);
``animation`` decodes the very same dict with ``decode`` and draws it with matplotlib. ``LAYOUT``, ``STYLE``,
``KEY``, ``SERIES`` and ``PANELS`` (parts, colours, the key, units) are read by both renderers, and the scene
carries what both show (titles, the view's size, the tested headway and its range, the bridged frames, the
panels' y-ranges), so the two pictures agree. docs/replay.md says how to read them.
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

from logiq_sql.core import units
from logiq_sql.core.errors import InputError, ScenarioError, arg
from logiq_sql.core.sql import bind, query_text
from logiq_sql.outputs.plots import ACTOR_COLOUR, EGO_COLOUR, PHASE_COLOURS
from logiq_sql.spec.plan import ALL_KINDS_CSV, DEFAULT_MIN_CLOSING_SPEED_MPS
from logiq_sql.spec.scenario import load_scenario
from logiq_sql.storage.db import open_current

MARGIN_S = 1.0  # shown before and after the match
OTHERS_RANGE_M = 60.0  # other road users within this distance of the ego are drawn (faint)
QUANTUM_M = 0.1  # positions and box sizes are stored in decimetres
VIEW_MIN_M = 18.0  # least half-width of the view
VIEW_MARGIN_M = 5.0  # room around the ego's and the actor's boxes at the tightest frame of the match
ANY_RANGE_M = 1e9  # the pairs are chosen already: relations.sql must not drop any by distance
BATCH = 400  # matches read per query: bounds memory for files with thousands of matches
MPH_PER_MPS = 1 / units.factor("mph")  # speeds are shown in mph, the unit of the spec's speed KPIs
CAP_S = 10.0  # the headway and TTC axis ends here; larger values are drawn on the top edge (tick label ">=10")

# the values plotted beside the map: (column, label, unit, scale of the stored integers). headway_s is the headway
# the scenario's phases test (_headway_tests), so its frames outside the tested range are bridged ones
SERIES = (("lon_gap_m", "gap", "m", 0.1), ("headway_s", "headway", "s", 0.1), ("ttc_s", "TTC", "s", 0.1),
          ("ego_speed_mph", "ego", "mph", 0.1), ("actor_speed_mph", "actor", "mph", 0.1))
# chart panels: axis label with unit, the series sharing it, the top of its axis at most
PANELS = (("gap (m)", ("lon_gap_m",), None), ("headway, TTC (s)", ("headway_s", "ttc_s"), CAP_S),
          ("speed (mph)", ("ego_speed_mph", "actor_speed_mph"), None))
# ego blue, actor red, other road users grey, junctions tan; the measures and the phases avoid those hues
SERIES_COLOURS = {"lon_gap_m": "#4d4d4d", "headway_s": "#7b3294", "ttc_s": "#b35806",
                  "ego_speed_mph": EGO_COLOUR, "actor_speed_mph": ACTOR_COLOUR}
STYLE = {
    "ego": EGO_COLOUR, "actor": ACTOR_COLOUR, "other": "#6b6b6b", "other_alpha": 0.3,
    "lane_fill": "#e6e6e6", "lane_edge": "#a0a0a0", "junction_fill": "#f5c16c", "junction_edge": "#b07d1a",
    "junction_alpha": 0.4, "background": "#fbfbf8", "phases": list(PHASE_COLOURS), "series": SERIES_COLOURS,
    "context": "#d9d9d9", "bridged": "#000000", "band": "#e7d4e8",
}
KEY = (("ego (SUT)", "ego"), ("actor", "actor"), ("other road users", "other"), ("lane", "lane_fill"),
       ("junction", "junction_fill"))
# fractions of the figure (x, y from the top, w, h): the map with its axes, its key, the phase timeline, the
# phases' key, and the charts on the right; the title is above the map (in the GIF; the report puts it over the
# canvas)
LAYOUT = {"width": 1000, "height": 600, "map": [0.06, 0.09, 0.55, 0.61], "key": [0.0, 0.755, 0.64, 0.04],
          "timeline": [0.06, 0.81, 0.55, 0.06], "phase_key": [0.0, 0.94, 0.64, 0.05],
          "charts": [0.70, 0.09, 0.29, 0.79]}
# the timeline's and the charts' time axis label
TIME_LABEL = "t (s of the drive)"

# relations.sql reads these tables; the replay gives it only the rows of the replayed pairs and no lane relations
# (same_lane and adjacent_side are not shown), so gap, headway and TTC are those matching computed
RELATION_INPUTS = {
    "tracks": "select * from pair_tracks",
    "ego_lanes": ("select distinct t.drive_id, t.actor_id as ego_id, t.frame, cast(null as varchar) as lane_id, "
                  "cast(null as bigint) as lane_run, t.drive_key, t.actor_key as ego_key "
                  "from pair_tracks as t inner join replay_windows as w on t.drive_id = w.drive_id "
                  "and t.actor_id = w.ego_id"),
    "actor_lanes": ("select drive_key, actor_key, frame, cast(null as varchar) as lane_id, "
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


def _headway_tests(con: duckdb.DuckDBPyConnection, windows: pl.DataFrame) -> pl.DataFrame:
    """Per (scenario, params_hash) of the replayed matches: the headway column its phase tests (the value of the
    scenario's headway_in_range conditions; the built-in scenarios test one column), the indexes of the phases that
    test it and the range bound in that run."""
    bound = dict(con.execute("select params_hash, any_value(params_json) from match_runs where params_hash in "
                             "(select params_hash from replay_windows) group by 1").fetchall())
    rows = []
    for name, params_hash in windows.select("scenario", "params_hash").unique().iter_rows():
        try:
            scenario = load_scenario(name)
        except ScenarioError:  # a scenario of another --scenario-path: its plain time headway, no range
            continue
        tested = [(k, c.value) for k, p in enumerate(scenario.phases, 1) for c in p.conditions
                  if c.name == "headway_in_range"]
        if tested:
            params = json.loads(bound[params_hash]) if params_hash in bound else scenario.bindings()
            rows.append((name, params_hash, tested[0][1], [k for k, _ in tested],
                         params.get("min_distance_from_sut_in_time_units_s"),
                         params.get("max_distance_from_sut_in_time_units_s")))
    return pl.DataFrame(rows, orient="row", schema={"scenario": pl.String, "params_hash": pl.String,
                                                    "hw_column": pl.String, "hw_phases": pl.List(pl.Int64),
                                                    "hw_lo": pl.Float64, "hw_hi": pl.Float64})


def _encode(windows: pl.DataFrame, frames: pl.DataFrame, others: pl.DataFrame, phases: pl.DataFrame,
            pet: dict[str, float | None], headway: pl.DataFrame) -> list[dict]:
    """One compact scene dict per match (vectorised per column; the loop is over matches)."""
    tested = (windows.select("match_id", "scenario", "params_hash", "start_frame", "end_frame")
              .join(headway, on=["scenario", "params_hash"], how="left"))
    # the frames inside a phase that tests the headway
    spans = (tested.select("match_id", pl.col("hw_phases").alias("phase_index")).explode("phase_index")
             .join(phases.select("match_id", "phase_index", "start_frame", "end_frame"), on=["match_id", "phase_index"]))
    in_tested = (frames.select("match_id", "frame").join(spans, on="match_id")
                 .filter(pl.col("frame").is_between("start_frame", "end_frame"))
                 .select("match_id", "frame").unique().with_columns(pl.lit(True).alias("in_tested")))
    frames = (frames.join(tested.drop("hw_phases"), on="match_id", how="left")
              .join(in_tested, on=["match_id", "frame"], how="left")).with_columns(
        pl.int_range(pl.len()).over("match_id").alias("i"),
        pl.col("ego_x_m").first().over("match_id").round().alias("ox"),
        pl.col("ego_y_m").first().over("match_id").round().alias("oy"),
        pl.when(pl.col("hw_column") == "follow_headway_s").then("follow_headway_s")
        .otherwise("time_headway_s").alias("headway_s"),
        (pl.col("ego_speed_mps") * MPH_PER_MPS).alias("ego_speed_mph"),
        (pl.col("actor_speed_mps") * MPH_PER_MPS).alias("actor_speed_mph"))
    inside = pl.col("frame").is_between("start_frame", "end_frame")
    # frames of the match at which its phase cannot have held, bridged by max_gap (docs/semantics.md): the actor
    # is not tracked, or, in a phase that tests the headway, the headway is undefined or out of its range
    out_of_range = (pl.col("in_tested").fill_null(False)
                    & ~pl.col("headway_s").is_between("hw_lo", "hw_hi").fill_null(False))
    frames = frames.with_columns((inside & (pl.col("actor_x_m").is_null() | out_of_range.fill_null(False)))
                                 .alias("bridged"))
    origin = frames.group_by("match_id").agg(pl.col("ox", "oy").first(), pl.col("t_s").first().alias("t0"))
    # the view: centred between the ego and the actor (on the ego while the actor is untracked), wide enough for
    # both boxes at every frame of the match, with the map's aspect (equal scale on both axes)
    reach = pl.max_horizontal((pl.col("ego_length_m") ** 2 + pl.col("ego_width_m") ** 2).sqrt(),
                              (pl.col("actor_length_m") ** 2 + pl.col("actor_width_m") ** 2).sqrt()) / 2
    half_x = ((pl.col("actor_x_m") - pl.col("ego_x_m")).abs() / 2).fill_null(0) + reach + VIEW_MARGIN_M
    half_y = ((pl.col("actor_y_m") - pl.col("ego_y_m")).abs() / 2).fill_null(0) + reach + VIEW_MARGIN_M
    aspect = (LAYOUT["map"][2] * LAYOUT["width"]) / (LAYOUT["map"][3] * LAYOUT["height"])
    view = frames.filter(inside).group_by("match_id").agg(
        pl.max_horizontal(half_x.max(), half_y.max() * aspect, pl.lit(VIEW_MIN_M)).alias("view_m"))
    bridged = frames.filter("bridged").group_by("match_id").agg(pl.col("i").alias("b"))
    q = QUANTUM_M
    coded = frames.with_columns(
        _q(pl.col("ego_x_m") - pl.col("ox"), q).alias("ex"), _q(pl.col("ego_y_m") - pl.col("oy"), q).alias("ey"),
        _q(pl.col("actor_x_m") - pl.col("ox"), q).alias("ax"), _q(pl.col("actor_y_m") - pl.col("oy"), q).alias("ay"),
        _q(pl.col("ego_heading_rad"), 0.01).alias("eh"), _q(pl.col("actor_heading_rad"), 0.01).alias("ah"),
        *[_q(pl.col(c), k).alias(c) for c, _, _, k in SERIES],
    ).with_columns(*[_delta(c) for c in ("frame", "ex", "ey", "ax", "ay", "eh", "ah")])
    per_match = coded.group_by("match_id", maintain_order=True).agg(
        "frame", "ex", "ey", "eh", "ax", "ay", "ah", *[c for c, _, _, _ in SERIES],
        _q(pl.col("ego_length_m").median(), q).alias("el"), _q(pl.col("ego_width_m").median(), q).alias("ew"),
        _q(pl.col("actor_length_m").median(), q).alias("al"), _q(pl.col("actor_width_m").median(), q).alias("aw"),
        pl.col("hw_column", "hw_lo", "hw_hi").first())
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
             .join(other, on="match_id", how="left").join(phase_rows, on="match_id", how="left")
             .join(bridged, on="match_id", how="left"))
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
            "s": {c: r[c] for c, _, _, _ in SERIES},
            # the headway shown: the column the scenario's phase tests and its range (None: time_headway_s)
            "hw": {"column": r["hw_column"] or "time_headway_s", "lo": r["hw_lo"], "hi": r["hw_hi"]},
            "b": r["b"] or [],
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
        r = s["view_m"] * 2  # the view is centred within view_m of the ego (between it and the actor)
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
        headway = _headway_tests(con, windows)
        phases = con.sql("select match_id, phase_index, phase, start_frame, end_frame from match_phases "
                         "where match_id in (select match_id from replay_ids)").pl()
        pet = dict(con.execute("select match_id, pet_between_sut_and_npc_s from kpis where match_id in "
                               "(select match_id from replay_ids)").fetchall()) if pet_column else {}
        encoded += _encode(windows, frames, others, phases, pet, headway)
    order = {m: i for i, m in enumerate(ids)}
    encoded.sort(key=lambda s: order[s["id"]])
    _shared_ranges(encoded)
    return encoded, _maps(con, encoded)


def _shared_ranges(encoded: list[dict]) -> None:
    """Give every scene the y-range of each panel over all the replayed matches of its scenario, so that the
    matches of one scenario are drawn to one scale (the headway and TTC panel ends at its cap)."""
    ranges: dict[str, list[list[float]]] = {}
    for s in encoded:
        mine = ranges.setdefault(s["scenario"], [[0.0, 1.0] for _ in PANELS])
        for k, (_, columns, cap) in enumerate(PANELS):
            values = [v for c in columns for v in s["s"][c] if v is not None]
            if values:  # stored integers: the range in the panel's unit, rounded outwards
                scale = next(x for c, _, _, x in SERIES if c == columns[0])
                mine[k][0] = min(mine[k][0], float(np.floor(min(values) * scale)))
                mine[k][1] = max(mine[k][1], float(np.ceil(max(values) * scale)))
            if cap is not None:
                mine[k] = [max(mine[k][0], 0.0), cap]
    for s in encoded:
        s["y"] = ranges[s["scenario"]]
        s["titles"] = list(titles(s))


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
        raise InputError(f"{arg('db', db)}: no such file (write one with `logiq-sql ingest` and `logiq-sql match`).")
    return open_current(db)


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
    scale = {c: k for c, _, _, k in SERIES}
    series = {c: np.array(vals, dtype=float) * scale[c] for c, vals in s["s"].items()}
    lanes, junctions = [], []
    if s.get("lanes"):
        m = s["lanes"]
        for key, into in (("lanes", lanes), ("junctions", junctions)):
            for ring in m[key]:
                xy = np.cumsum(np.asarray(ring, dtype=float).reshape(-1, 2), axis=0) * m["q"] + m["origin"]
                into.append(xy)
    return {"t_s": s["t0"] + (frames - frames[0]) * s["dt"], "ego": actor(s["e"]), "actor": actor(s["a"]),
            "others": others, "series": series, "phases": s["p"], "lanes": lanes, "junctions": junctions,
            "bridged": np.asarray(s["b"], dtype=int)}


def box_corners(x: float, y: float, h: float, length: float, width: float) -> np.ndarray:
    """The four corners of a box centred on (x, y) with heading h: front left, front right, rear right, rear left."""
    c, s = np.cos(h), np.sin(h)
    along = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    return np.column_stack([x + along[:, 0] * c - along[:, 1] * s, y + along[:, 0] * s + along[:, 1] * c])


# ---- matplotlib (notebooks, GIF and MP4): the same scene, layout and colours as REPLAY_JS ----

def _axes_rect(part: list[float]) -> list[float]:
    """A LAYOUT part (x, y from the top, w, h; fractions) as matplotlib's (left, bottom, w, h)."""
    x, y, w, h = part
    return [x, 1 - y - h, w, h]


MAX_FRAMES = 150  # a replay longer than this skips frames evenly (GIF size, notebook size)


def _step(n: int, max_frames: int) -> int:
    return max(1, -(-n // max_frames))


def titles(s: dict) -> tuple[str, str]:
    """The replay's two title lines (the report's dialog shows the same): what and when, then who."""
    ego = "recorded ego" if s["ego"] == "ego" else f"ego {s['ego']}"
    pet = "" if s.get("pet_s") is None else f", PET {s['pet_s']:.2f} s"
    return (f"{s['scenario']}: match {s['start_s']:.1f} to {s['end_s']:.1f} s{pet}",
            f"drive {s['drive']}, {ego} (blue), actor {s['actor']} (red)")


def view_centres(d: dict) -> np.ndarray:
    """Per frame, the centre of the view: midway between the ego and the actor, on the ego while the actor is
    untracked (replay.js's viewCentre is the same rule)."""
    ego = np.column_stack([d["ego"]["x"], d["ego"]["y"]])
    actor = np.column_stack([d["actor"]["x"], d["actor"]["y"]])
    mid = (ego + actor) / 2
    return np.where(np.isnan(mid), ego, mid)


def scale_bar_m(width_m: float) -> float:
    """The scale bar's length: the least round length of at least a sixth of the view's width (replay.js:
    scaleBar)."""
    return float(next((v for v in (5, 10, 20, 50, 100, 200, 500) if v >= width_m / 6), 1000))


def actor_note(t_s: np.ndarray, x: np.ndarray, i: int) -> str | None:
    """Why the actor has no value at frame i: its track has not begun, has ended, or has a hole (bridged)."""
    if not np.isnan(x[i]):
        return None
    seen = np.flatnonzero(~np.isnan(x))
    if not seen.size:
        return "actor not tracked"
    if i < seen[0]:
        return f"actor track starts at t={t_s[seen[0]]:.1f} s"
    if i > seen[-1]:
        return f"actor track ends at t={t_s[seen[-1]]:.1f} s"
    return "actor not tracked here"


def arrow_points(x: float, y: float, h: float, length: float, width: float) -> np.ndarray:
    """The heading arrow drawn on a box: a shaft from the centre with a head at the front edge (7 points)."""
    head, shaft = min(width * 0.8, length * 0.45), width * 0.12
    tip = length / 2
    local = np.array([[-length * 0.25, -shaft], [tip - head, -shaft], [tip - head, -head / 2], [tip, 0],
                      [tip - head, head / 2], [tip - head, shaft], [-length * 0.25, shaft]])
    c, s = np.cos(h), np.sin(h)
    return np.column_stack([x + local[:, 0] * c - local[:, 1] * s, y + local[:, 0] * s + local[:, 1] * c])


def value_text(name: str, unit: str, value: float, cap: float | None) -> str:
    if np.isnan(value):
        return f"{name} undefined"
    return f"{name} {value:.1f} {unit}" + (f" (axis ends at {cap:.0f})" if cap is not None and value > cap else "")


def animation(db: str | Path | duckdb.DuckDBPyConnection | dict, match_id: str | None = None, step: int | None = None,
              max_frames: int = MAX_FRAMES):
    """A ``matplotlib.animation.FuncAnimation`` of one match (in a notebook: ``HTML(anim.to_jshtml())``).

    ``db`` is a DuckDB file or connection (with ``match_id``) or a scene from ``scene``. Every ``step``-th frame
    is drawn; by default at most ``max_frames`` frames, at the recorded speed.
    """
    from matplotlib.animation import FuncAnimation
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    s = db if isinstance(db, dict) else scene(db, match_id)
    d = decode(s)
    t = d["t_s"]
    n = len(t)
    step = step or _step(n, max_frames)
    t_lo, t_hi = t[0], t[-1] + s["dt"]
    fig = Figure(figsize=(LAYOUT["width"] / 100, LAYOUT["height"] / 100), dpi=100, facecolor="white")
    first, second = titles(s)
    fig.text(0.01, 0.99, first, fontsize=8, va="top", weight="bold")
    fig.text(0.01, 0.955, second, fontsize=7, va="top")

    # the map: map coordinates in metres, equal scale, a scale bar, the view between the ego and the actor
    ax = fig.add_axes(_axes_rect(LAYOUT["map"]))
    ax.set_facecolor(STYLE["background"])
    ax.set_aspect("equal", adjustable="datalim")
    ax.tick_params(labelsize=6)
    ax.set_xlabel("x (m)", fontsize=7, labelpad=1)
    ax.set_ylabel("y (m)", fontsize=7, labelpad=1)
    ax.add_collection(PolyCollection(d["lanes"], facecolor=STYLE["lane_fill"], edgecolor=STYLE["lane_edge"],
                                     linewidth=0.6, zorder=1))
    ax.add_collection(PolyCollection(d["junctions"], facecolor=STYLE["junction_fill"],
                                     edgecolor=STYLE["junction_edge"], alpha=STYLE["junction_alpha"], zorder=2))
    others = PolyCollection([], facecolor=STYLE["other"], edgecolor="black", alpha=STYLE["other_alpha"], zorder=3)
    ax.add_collection(others)
    trails = {k: ax.plot([], [], color=STYLE[k], alpha=0.5, linewidth=1.5, zorder=4)[0] for k in ("ego", "actor")}
    boxes = {k: ax.add_patch(Polygon(np.zeros((4, 2)), closed=True, facecolor=STYLE[k], edgecolor="black",
                                     zorder=5)) for k in ("ego", "actor")}
    arrows = {k: ax.add_patch(Polygon(np.zeros((7, 2)), closed=True, facecolor="white", edgecolor="none",
                                      zorder=6)) for k in ("ego", "actor")}
    half_w = s["view_m"]
    half_h = half_w * (LAYOUT["map"][3] * LAYOUT["height"]) / (LAYOUT["map"][2] * LAYOUT["width"])
    bar = scale_bar_m(half_w * 2)
    ax.add_artist(AnchoredSizeBar(ax.transData, bar, f"{bar:.0f} m", "lower left", pad=0.3, frameon=True,
                                  size_vertical=half_h / 60, fontproperties={"size": 6}))
    centres = view_centres(d)
    key = [Patch(facecolor=STYLE[c], edgecolor="black", label=n) for n, c in KEY]
    key.append(Line2D([], [], color="black", marker=">", linestyle="-", markersize=4, label="heading"))
    x, y, w, h = LAYOUT["key"]
    fig.legend(handles=key, loc="center left", bbox_to_anchor=(x, 1 - y - h / 2), ncols=len(key), fontsize=6.5,
               frameon=False, handlelength=1.2, columnspacing=1.0)

    # the phases over drive time, the context before and after the match shaded
    tl = fig.add_axes(_axes_rect(LAYOUT["timeline"]))
    tl.set_xlim(t_lo, t_hi)
    tl.set_ylim(0, 1)
    tl.set_yticks([])
    tl.tick_params(labelsize=6, pad=1)
    tl.set_xlabel(TIME_LABEL, fontsize=7, labelpad=1)
    phase_keys = []
    for index, name, a, b in d["phases"]:
        a, b = (0 if a is None else a), (n - 1 if b is None else b)
        colour = STYLE["phases"][(index - 1) % len(STYLE["phases"])]
        tl.broken_barh([(t[a], t[b] - t[a] + s["dt"])], (0.15, 0.7), color=colour)
        phase_keys.append(Patch(facecolor=colour, label=f"{index}. {name}"))
    charts = []
    rows = len(PANELS)
    gap = 0.045  # between the panels, for the value line above each
    x, y, w, h = LAYOUT["charts"]
    for k in range(rows):
        part = [x, y + k * (h + gap) / rows, w, (h + gap) / rows - gap]
        charts.append(fig.add_axes(_axes_rect(part)))
    for a in [tl, *charts]:
        for lo, hi in ((t_lo, s["start_s"]), (s["end_s"] + s["dt"], t_hi)):
            if hi > lo:
                a.axvspan(lo, hi, color=STYLE["context"], alpha=0.6, linewidth=0, zorder=0)
    bridged = d["bridged"]
    if bridged.size:
        tl.plot(t[bridged] + s["dt"] / 2, np.full(bridged.size, 0.5), "|", color=STYLE["bridged"], markersize=7)
    phase_keys.append(Patch(facecolor=STYLE["context"], label=f"context ({MARGIN_S:.0f} s either side)"))
    if bridged.size:
        phase_keys.append(Line2D([], [], color=STYLE["bridged"], marker="|", linestyle="none", label="bridged frame"))
    if s["hw"]["lo"] is not None:
        phase_keys.append(Patch(facecolor=STYLE["band"], label="headway range tested"))
    x, y, w, h = LAYOUT["phase_key"]
    # one row while the names fit across the figure (about 190 characters at this size), else two
    chars = sum(len(p.get_label()) + 6 for p in phase_keys)
    fig.legend(handles=phase_keys, loc="center left", bbox_to_anchor=(x, 1 - y - h / 2),
               ncols=len(phase_keys) if chars <= 190 else -(-len(phase_keys) // 2),
               fontsize=6.5, frameon=False, handlelength=1.2, columnspacing=1.0)
    cursors = [tl.axvline(t[0], color="black", linewidth=2)]

    values = []
    units_of = {c: (name, unit) for c, name, unit, _ in SERIES}
    hw_name = "follow headway" if s["hw"]["column"] == "follow_headway_s" else "headway"
    for k, (cax, (label, columns, cap)) in enumerate(zip(charts, PANELS, strict=True)):
        cax.tick_params(labelsize=6, pad=1)
        cax.set_xlim(t_lo, t_hi)
        lo, hi = s["y"][k]
        cax.set_ylim(lo, hi * (1 if cap else 1.05))
        cax.set_ylabel(label, fontsize=7, labelpad=1)
        if cap:
            ticks = np.linspace(0, cap, 5)
            cax.set_yticks(ticks, [f"{v:g}" for v in ticks[:-1]] + [f"\u2265{cap:g}"])
        if k < rows - 1:
            cax.tick_params(labelbottom=False)
        else:
            cax.set_xlabel(TIME_LABEL, fontsize=7, labelpad=1)
        if "headway_s" in columns and s["hw"]["lo"] is not None:
            cax.axhspan(s["hw"]["lo"], min(s["hw"]["hi"], cap), color=STYLE["band"], linewidth=0, zorder=0.5)
        for j, c in enumerate(columns):
            series = d["series"][c]
            cax.plot(t, np.minimum(series, cap) if cap else series, color=STYLE["series"][c], linewidth=1.2)
            if c == "headway_s" and bridged.size:
                cax.plot(t[bridged], np.minimum(np.nan_to_num(series[bridged], nan=0.0), cap), "x",
                         color=STYLE["bridged"], markersize=3)
            name, unit = units_of[c]
            name = hw_name if c == "headway_s" else name
            # the value line sits above the panel, one series at each end, never under a curve
            text = cax.text(0.0 if j == 0 else 1.0, 1.02, "", transform=cax.transAxes, fontsize=6.5,
                            ha="left" if j == 0 else "right", va="bottom", color=STYLE["series"][c])
            values.append((text, series, name, unit, cap, c != "ego_speed_mph", j))
        cursors.append(cax.axvline(t[0], color="black", linewidth=1))

    def draw(i: int):
        cx, cy = centres[i]
        ax.set_xlim(cx - half_w, cx + half_w)
        ax.set_ylim(cy - half_h, cy + half_h)
        polys = [box_corners(o["x"][i], o["y"][i], o["h"][i], o["l"], o["w"]) for o in d["others"]
                 if not np.isnan(o["x"][i])]
        others.set_verts(polys)
        for k in ("ego", "actor"):
            a = d[k]
            trails[k].set_data(a["x"][:i + 1], a["y"][:i + 1])
            visible = not np.isnan(a["x"][i])
            boxes[k].set_visible(visible)
            arrows[k].set_visible(visible)
            if visible:
                boxes[k].set_xy(box_corners(a["x"][i], a["y"][i], a["h"][i], a["l"], a["w"]))
                arrows[k].set_xy(arrow_points(a["x"][i], a["y"][i], a["h"][i], a["l"], a["w"]))
        for cursor in cursors:
            cursor.set_xdata([t[i], t[i]])
        note = actor_note(t, d["actor"]["x"], i)
        for text, series, name, unit, cap, needs_actor, j in values:
            if needs_actor and note:  # said once per panel, not as a bare "n/a" under every value
                text.set_text(note if j == 0 else "")
            else:
                text.set_text(value_text(name, unit, series[i], cap))
        return []

    draw(0)
    anim = FuncAnimation(fig, draw, frames=range(0, n, step), interval=1000 * s["dt"] * step, blit=False)
    anim.parts = {"figure": fig, "map": ax, "boxes": boxes, "draw": draw}  # for tests: what is drawn where
    return anim


def save(db: str | Path, match_id: str, out: str | Path, step: int | None = None) -> Path:
    """Write the replay of one match as a GIF (Pillow) or an MP4 (ffmpeg from imageio-ffmpeg)."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InputError(f"{arg('out', out)}: write a .gif or an .mp4 file.")
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
