"""The path a researcher would otherwise take: follower_vehicle and cyclist_close_to_moving_sut written as
loops over drives, egos and actor pairs in pandas and numpy (vectorised within one pair), as research code
usually is. It exists to be timed against the SQL pipeline and to give the same matches.

Inputs, read from a file that ``match`` has run on: tracks, track_lanes, lanes, lane_successors,
drive_inputs and the ego's lane per frame (``ego_lanes``: lane runs with the lane-change tolerance, the one
piece taken from logiq_sql, since lane-change detection is not what is compared). Everything else is computed
here, per pair: the actor's lane, the ego-frame geometry, bumper gaps, box distance, headway, the lane and
road tests, the follow gap, the nearest follower, islands and duration rules, with the formulas of docs/semantics.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd

from logiq_sql.spec.plan import OBJECT_RELATION_RANGE_M, resolve_scenarios

VEHICLE_KINDS = {"vehicle", "truck", "bus", "trailer", "motorcycle", "emergency_vehicle"}


def _load(db: Path) -> dict[str, pd.DataFrame]:
    with duckdb.connect(str(db), read_only=True) as con:
        return {t: con.sql(f"select * from {t}").df() for t in
                ("tracks", "track_lanes", "lanes", "lane_successors", "drive_inputs", "ego_lanes")}


def _actor_lanes(track_lanes: pd.DataFrame, tolerance_m: float) -> pd.DataFrame:
    near = track_lanes[(track_lanes["dist_m"] <= tolerance_m) & (track_lanes["heading_diff_rad"].abs() < math.pi / 2)]
    near = near.assign(abs_diff=near["heading_diff_rad"].abs()).sort_values(
        ["drive_id", "actor_id", "frame", "dist_m", "abs_diff", "lane_id"])
    return near.drop_duplicates(["drive_id", "actor_id", "frame"])[["drive_id", "actor_id", "frame", "lane_id"]]


def _geometry(e: pd.DataFrame, a: pd.DataFrame) -> dict[str, np.ndarray]:
    """Ego-frame geometry of one pair on its common frames (the formulas of queries/relations/relations.sql)."""
    h = e["heading_rad"].to_numpy()
    ddx, ddy = a["x_m"].to_numpy() - e["x_m"].to_numpy(), a["y_m"].to_numpy() - e["y_m"].to_numpy()
    dx, dy = ddx * np.cos(h) + ddy * np.sin(h), ddy * np.cos(h) - ddx * np.sin(h)
    rel = a["heading_rad"].to_numpy() - h
    rel = np.arctan2(np.sin(rel), np.cos(rel))
    c, s = np.cos(rel), np.sin(rel)
    le, we = e["length_m"].to_numpy(), e["width_m"].to_numpy()
    la, wa = a["length_m"].to_numpy(), a["width_m"].to_numpy()
    u, v = -(dx * c + dy * s), dx * s - dy * c
    lon_raw = np.abs(dx) - le / 2 - np.abs(la / 2 * c) - np.abs(wa / 2 * s)
    lat_raw = np.abs(dy) - we / 2 - np.abs(la / 2 * s) - np.abs(wa / 2 * c)
    u_raw = np.abs(u) - la / 2 - np.abs(le / 2 * c) - np.abs(we / 2 * s)
    v_raw = np.abs(v) - wa / 2 - np.abs(le / 2 * s) - np.abs(we / 2 * c)
    corners = []
    for p, q in ((1, 1), (1, -1), (-1, 1), (-1, -1)):  # actor corners in the ego frame, ego corners in the actor's
        ax, ay = dx + p * la / 2 * c - q * wa / 2 * s, dy + p * la / 2 * s + q * wa / 2 * c
        corners.append(np.hypot(np.maximum(np.abs(ax) - le / 2, 0), np.maximum(np.abs(ay) - we / 2, 0)))
        eu, ev = u + p * le / 2 * c + q * we / 2 * s, v - p * le / 2 * s + q * we / 2 * c
        corners.append(np.hypot(np.maximum(np.abs(eu) - la / 2, 0), np.maximum(np.abs(ev) - wa / 2, 0)))
    overlap = (lon_raw <= 0) & (lat_raw <= 0) & (u_raw <= 0) & (v_raw <= 0)
    return {"dx": dx, "lon_gap": np.maximum(lon_raw, 0), "lat_gap": np.maximum(lat_raw, 0),
            "dist2": ddx * ddx + ddy * ddy, "box_distance": np.where(overlap, 0.0, np.minimum.reduce(corners))}


def _islands(frames: np.ndarray) -> np.ndarray:
    """Island number of each frame of a sorted frame array (consecutive frames share one)."""
    return frames - np.arange(len(frames))


def _bound_elsewhere(ts, runs, ego_lane, actor_lane, road, behind, in_range, visited, nxt, map_id,
                     limit_s) -> np.ndarray:
    """Per frame: the actor is on a lane of the ego's road that the ego has left together with its successor, and,
    within limit_s of leaving it, drives on into a successor of it but never into a lane the ego entered after it."""
    ego_next = np.array([e in nxt.get((map_id, a), ()) for e, a in zip(ego_lane, actor_lane, strict=True)],
                        dtype=bool)
    left = road & (actor_lane != ego_lane) & ~ego_next
    first = np.array([visited.loc[(run, lane), "min"] if lf else np.nan
                      for run, lane, lf in zip(runs, actor_lane, left, strict=True)], dtype=float)
    seen = left & behind & in_range
    lanes_of_actor = pd.notna(actor_lane)
    bound = set()
    for lane, lane_first in {(a, f) for a, f in zip(actor_lane[seen], first[seen], strict=True)}:
        last = ts[seen & (actor_lane == lane) & (first == lane_first)].max()
        after = set(actor_lane[in_range & lanes_of_actor & (ts > last) & (ts <= last + limit_s) & (actor_lane != lane)])
        entered_later = {x for (_, x), when in visited.iterrows() if when["min"] > lane_first}
        if after & nxt.get((map_id, lane), set()) and not after & entered_later:
            bound.add(lane)
    return left & np.isin(actor_lane, list(bound))


def follower_vehicle(t: dict[str, pd.DataFrame], p: dict[str, object], range_m: float) -> pd.DataFrame:
    kinds = {k for k in str(p["kinds_csv"]).split(",") if k}
    lanes = _actor_lanes(t["track_lanes"], float(p["lane_calculation_tolerance_length_m"]))
    # the lane line (queries/relations/lane_line.sql): successors and theirs, predecessors and theirs
    line = {(r.map_id, r.lane_id, r.lane_id) for r in t["lanes"].itertuples()}
    nxt: dict[tuple[str, str], set[str]] = {}
    for r in t["lane_successors"].itertuples():
        nxt.setdefault((r.map_id, r.lane_id), set()).add(r.successor_id)
    for (m, a), bs in nxt.items():
        for b in bs | {c for b in bs for c in nxt.get((m, b), ())}:
            line |= {(m, a, b), (m, b, a)}
    maps = dict(zip(t["drive_inputs"]["drive_id"], t["drive_inputs"]["map_id"], strict=True))
    lanes_by_drive = dict(tuple(lanes.groupby("drive_id")))
    # the lanes each actor's centre is inside (headed their way), per frame: where two lanes overlap (a fork, a lane
    # widening into two) a centre inside both is in either
    tl = t["track_lanes"]
    inside_rows = tl[(tl["dist_m"] == 0) & (tl["heading_diff_rad"].abs() < math.pi / 2)]
    inside = {key: set(zip(g["frame"], g["lane_id"], strict=True))
              for key, g in inside_rows.groupby(["drive_id", "actor_id"])}
    ego_lanes = dict(tuple(t["ego_lanes"].groupby(["drive_id", "ego_id"])))
    out = []
    for drive_id, drive in t["tracks"].groupby("drive_id"):
        tracks = drive.merge(lanes_by_drive.get(drive_id, lanes.iloc[:0]), how="left",
                             on=["drive_id", "actor_id", "frame"])
        actors = {a: g.set_index("frame") for a, g in tracks.groupby("actor_id")}
        for (d, ego), el in ego_lanes.items():
            if d != drive_id:
                continue
            e = actors[ego].join(el.set_index("frame")[["lane_id", "lane_run"]], rsuffix="_ego", how="inner")
            in_lane = el.dropna(subset=["lane_id"])
            visited = in_lane.groupby(["lane_run", "lane_id"])["t_s"].agg(["min", "max"])
            first_lane = in_lane.sort_values("frame").drop_duplicates("lane_run").set_index("lane_run")["lane_id"]
            # lanes leaving the road: direct successors of a lane driven in the run, with when it was driven
            leaving: dict[tuple[int, str], list[tuple[float, float]]] = {}
            for (run, lane), when in visited.iterrows():
                for nx in nxt.get((maps[drive_id], lane), ()):
                    leaving.setdefault((run, nx), []).append((when["min"], when["max"]))
            rows = []
            for actor, a in actors.items():
                if actor == ego:
                    continue
                frames = e.index.intersection(a.index)
                if frames.empty:
                    continue
                ee, aa = e.loc[frames], a.loc[frames]
                g = _geometry(ee, aa)
                vehicle = aa["kind"].iloc[0] in VEHICLE_KINDS
                limit = range_m if vehicle else min(range_m, OBJECT_RELATION_RANGE_M)
                ego_lane, actor_lane = ee["lane_id_ego"].to_numpy(), aa["lane_id"].to_numpy()
                # the same lane: the lane line, or one centre inside the other's lane
                ego_inside, actor_inside = inside.get((drive_id, ego), set()), inside.get((drive_id, actor), set())
                same = np.array([(maps[drive_id], x, y) in line or (f, x) in actor_inside or (f, y) in ego_inside
                                 for f, x, y in zip(frames, ego_lane, actor_lane, strict=True)], dtype=bool)
                # the actor's road: the ego's lane, a lane the ego drove in during the last same_road_limit of
                # its lane run, or (while the ego is in the first lane of its lane run) the same lane
                first = np.array([first_lane.get(run) == x for run, x in zip(ee["lane_run"], ego_lane, strict=True)])
                road = np.array([
                    (run, lane) in visited.index and visited.loc[(run, lane), "min"] <= ts
                    and visited.loc[(run, lane), "max"] >= ts - float(p["same_road_limit_s"])
                    for run, lane, ts in zip(ee["lane_run"], actor_lane, ee["t_s"], strict=True)])
                on_road = (ego_lane == actor_lane) | road | (same & first)
                # a road user turning off the road still stands between the ego and those behind it
                limit_s = float(p["same_road_limit_s"])
                turning = ~on_road & np.array([
                    any(lo <= ts and hi >= ts - limit_s for lo, hi in leaving.get((run, lane), ()))
                    for run, lane, ts in zip(ee["lane_run"], actor_lane, ee["t_s"], strict=True)])
                # an actor bound for another exit stands between but does not follow
                elsewhere = _bound_elsewhere(ee["t_s"].to_numpy(), ee["lane_run"].to_numpy(), ego_lane, actor_lane,
                                             road, g["dx"] < 0, g["dist2"] <= limit * limit, visited, nxt,
                                             maps[drive_id], limit_s)
                # behind: past the ego's rear bumper, or along the road on a lane of the ego's line that it drove
                # before its present one, boxes apart (a long ego turning sharply swings its rear across that lane)
                behind_ego = (g["lon_gap"] > 0) | (same & road & (actor_lane != ego_lane) & (g["box_distance"] > 0))
                keep = ((g["dist2"] <= limit * limit) & pd.notna(ego_lane) & (g["dx"] < 0) & behind_ego
                        & (on_road | turning))
                if not keep.any():
                    continue
                # the gap along an L-shaped path on the ego's axes, never shorter than the distance between boxes
                gap = np.maximum(g["lon_gap"] + g["lat_gap"], g["box_distance"])
                speed = aa["speed_mps"].to_numpy()
                headway = np.where(speed > 0, gap / np.where(speed > 0, speed, 1), np.nan)
                rows.append(pd.DataFrame({
                    "actor_id": actor, "kind": aa["kind"].iloc[0], "frame": frames.to_numpy()[keep],
                    "t_s": ee["t_s"].to_numpy()[keep], "lane_run": ee["lane_run"].to_numpy()[keep],
                    "gap": gap[keep], "headway": headway[keep], "turning": turning[keep],
                    "elsewhere": elsewhere[keep]}))
            if not rows:
                continue
            behind = pd.concat(rows).sort_values(["frame", "gap", "actor_id"]).drop_duplicates("frame")
            behind = behind[~behind["turning"] & ~behind["elsewhere"] & behind["kind"].isin(kinds)
                            & (behind["headway"] >= float(p["min_distance_from_sut_in_time_units_s"]))
                            & (behind["headway"] <= float(p["max_distance_from_sut_in_time_units_s"]))]
            for (actor, _run), g in behind.groupby(["actor_id", "lane_run"]):
                g = g.sort_values("frame")
                for _, island in g.groupby(_islands(g["frame"].to_numpy())):
                    if island["t_s"].max() - island["t_s"].min() >= float(p["min_scenario_duration_s"]):
                        out.append((drive_id, ego, actor, int(island["frame"].min()), int(island["frame"].max())))
    return pd.DataFrame(out, columns=["drive_id", "ego_id", "actor_id", "start_frame", "end_frame"])


def cyclist_close_to_moving_sut(t: dict[str, pd.DataFrame], p: dict[str, object], range_m: float) -> pd.DataFrame:
    dts = dict(zip(t["drive_inputs"]["drive_id"], t["drive_inputs"]["dt_s"], strict=True))
    egos = t["ego_lanes"][["drive_id", "ego_id"]].drop_duplicates()
    out = []
    for drive_id, drive in t["tracks"].groupby("drive_id"):
        actors = {a: g.set_index("frame") for a, g in drive.groupby("actor_id")}
        piece_frames = math.floor(float(p["max_phase_duration_s"]) / dts[drive_id] + 1e-9) + 1
        for ego in egos[egos["drive_id"] == drive_id]["ego_id"]:
            e = actors[ego]
            for actor, a in actors.items():
                if actor == ego or a["kind"].iloc[0] != "cyclist":
                    continue
                frames = e.index.intersection(a.index)
                ee, aa = e.loc[frames], a.loc[frames]
                g = _geometry(ee, aa)
                limit = min(range_m, OBJECT_RELATION_RANGE_M)
                keep = ((g["dist2"] <= limit * limit) & (ee["speed_mps"].to_numpy() >= float(p["sut_minimal_speed_mps"]))
                        & (g["box_distance"] >= float(p["min_distance_from_cyclist_m"]))
                        & (g["box_distance"] <= float(p["max_distance_from_cyclist_m"])))
                close = np.asarray(frames[keep])
                for island in np.split(close, np.flatnonzero(np.diff(close) != 1) + 1) if close.size else []:
                    for start in range(0, island.size, piece_frames):
                        piece = island[start:start + piece_frames]
                        out.append((drive_id, ego, actor, int(piece[0]), int(piece[-1])))
    return pd.DataFrame(out, columns=["drive_id", "ego_id", "actor_id", "start_frame", "end_frame"])


BASELINES = {"follower_vehicle": follower_vehicle, "cyclist_close_to_moving_sut": cyclist_close_to_moving_sut}
# the meaning the baseline implements: a phase ends at every missing frame (no gap bridging, so no jitter rule):
# the SQL matcher is compared with it under these values (benchmarks/tiers.py, tests/whole/test_baseline.py)
SAME_MEANING = {"max_gap": "0s"}


def run(db: Path, overrides: dict[str, str] | None = None, range_m: float = 200.0) -> dict[str, pd.DataFrame]:
    """Each baseline's matches on the drives of ``db`` (the egos of the last match run: ego_lanes)."""
    tables = _load(db)
    scenarios = resolve_scenarios(list(BASELINES), overrides or {})
    return {s.name: BASELINES[s.name](tables, s.bindings(), range_m) for s in scenarios}
