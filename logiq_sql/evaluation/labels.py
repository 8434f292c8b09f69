"""Ground-truth labels of LogIQ scenarios from a SUMO run's own records, for ``logiq-sql evaluate``.

Why: logiq_sql finds scenarios from the tracks and the map only. SUMO knows what it simulated: each vehicle's
leader and the gap to it (FCD leaderID, leaderGap), every lane change (lanechange-output), each vehicle's lane
(FCD lane and lane position) and its exact box (FCD front bumper and angle, vType length and width), the
junction's connections, internal lanes and their shapes (the network) and every link's signal state
(tls_states). Labels built from those records, never from logiq_sql's SQL, are an independent reference. The
definitions, and why, are in docs/evaluation.md; parameter values come from the scenario files
(``load_scenario``), in SI units.

Everything is vectorised Polars, numpy and shapely over the whole run: no Python loop over rows, pairs or
timestamps (only over the network's XML elements when it is read).
"""

from __future__ import annotations

import gzip
import math
import zlib
from pathlib import Path

import numpy as np
import polars as pl
import shapely

from logiq_sql.core.errors import InputError, ScenarioError, did_you_mean
from logiq_sql.core.schema import VEHICLE_KINDS
from logiq_sql.ingestion.readers.sumo import (
    parse_sumo_xml,
    read_fcd,
    read_vtypes,
    run_file,
    run_folders,
    sample_period_s,
    shape_coords,
    xml_records,
)
from logiq_sql.spec.scenario import load_scenario

SCENARIOS = ("follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut",
             "unprotected_left_turn_with_yield_and_traffic_light")
LABEL_SCHEMA = {
    "drive_id": pl.String, "scenario": pl.String, "ego_id": pl.String, "actor_id": pl.String,
    "start_s": pl.Float64, "end_s": pl.Float64, "source": pl.String,
}
EPS = 1e-9  # durations are multiples of dt: compare them to limits without float noise
_FCD_COLUMNS = ("vehicle_id", "type_id", "x_m", "y_m", "angle_deg", "speed_mps", "lane_id", "lane_pos_m",
                "leader_id", "leader_gap_m")
_SEGMENT_REACH = 2  # lane segments of a vehicle searched for the other one's edge: an internal lane, the next edge


# ------------------------------------------------------------------------------------------------- parameters

def scenario_values(names: list[str], overrides: dict[str, str] | None = None) -> dict[str, dict[str, object]]:
    """Per scenario, parameter name -> value in SI units (``kinds``: a tuple, unset = the vehicle kinds).

    An override applies to every scenario that declares the parameter, as for ``match``.
    """
    overrides = overrides or {}
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise ScenarioError(f"label sumo: no labeller for scenario '{unknown[0]}'.{did_you_mean(unknown[0], SCENARIOS)}"
                            f"\n\nHint: the labelled scenarios are {', '.join(SCENARIOS)}.")
    scenarios = [load_scenario(n) for n in names]
    known = {p for s in scenarios for p in s.params}
    for name, text in overrides.items():
        if name not in known:
            raise ScenarioError(f"--set {name}={text}: no labelled scenario has a parameter '{name}'."
                                f"{did_you_mean(name, sorted(known))}")
    out = {}
    for s in scenarios:
        s = s.with_overrides({k: v for k, v in overrides.items() if k in s.params})
        values = {p.name: p.value for p in s.params.values()}
        if "kinds" in values and values["kinds"] is None:
            values["kinds"] = VEHICLE_KINDS
        out[s.name] = values
    return out


# ----------------------------------------------------------------------------------------------- the run

def load_run(folder: str | Path) -> tuple[str, float, pl.DataFrame, pl.DataFrame]:
    """(drive_id, dt_s, rows, changes) of a SUMO run folder.

    rows: one per FCD vehicle row whose vType is known (SUMO's lane_id and lane_pos_m among the FCD columns),
    with frame, kind, vclass, length_m, width_m, edge_id,
    lane_index, lane_run (count of the vehicle's lane changes so far) and lane_segment (count of lane switches
    of any kind so far: lane changes and moves onto the next lane of the route).
    changes: one per lanechange-output record: vehicle_id, frame, t_s, from_lane, to_lane.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; pass a SUMO run folder (logiq-sql simulate writes one).")
    fcd_path = run_file(folder, ("fcd*.xml", "fcd*.xml.gz", "fcd*.parquet"), "FCD",
                    "run sumo with --fcd-output fcd.xml.gz and the leader attributes (logiq-sql simulate does).")
    lc_path = run_file(folder, ("lanechange*.xml", "lanechange*.xml.gz"), "lane-change output",
                   "run sumo with --lanechange-output lanechange.xml.gz (logiq-sql simulate does).")
    if not _has_leaders(fcd_path):
        raise InputError(f"{fcd_path}: the FCD has no leaderID/leaderGap attributes. Fix: run sumo with "
                         "--fcd-output.attributes including leaderID,leaderSpeed,leaderGap and "
                         "--fcd-output.max-leader-distance 250, as XML (logiq-sql simulate does).")
    fcd = read_fcd(fcd_path, _FCD_COLUMNS)
    dt = sample_period_s(fcd, fcd_path)
    vtypes = read_vtypes(folder).select("type_id", "vclass", "kind", "length_m", "width_m")
    changes = xml_records(lc_path, "change", ("id", "time", "from", "to"), "</lanechanges>").select(
        vehicle_id=pl.col("id"), t_s=pl.col("time").cast(pl.Float64), from_lane=pl.col("from"),
        to_lane=pl.col("to"),
    ).with_columns(frame=(pl.col("t_s") / dt).round().cast(pl.Int64))
    flags = changes.select("vehicle_id", "frame").unique().with_columns(is_change=pl.lit(1, pl.Int64))
    lane = pl.col("lane_id")
    rows = (
        fcd.join(vtypes, on="type_id", how="inner")
        .with_columns(frame=(pl.col("t_s") / dt).round().cast(pl.Int64),
                      edge_id=lane.str.extract(r"^(.*)_\d+$"),
                      lane_index=lane.str.extract(r"_(\d+)$").cast(pl.Int64))
        .join(flags, on=["vehicle_id", "frame"], how="left")
        .with_columns(
            lane_run=pl.col("is_change").fill_null(0).cum_sum().over("vehicle_id", order_by="frame"),
            lane_segment=(lane != lane.shift(1)).fill_null(False).cast(pl.Int64).cum_sum()
            .over("vehicle_id", order_by="frame"))
        .drop("is_change")
    )
    return folder.name, dt, rows, changes


def _has_leaders(fcd_path: Path) -> bool:
    """Whether SUMO wrote the leader attributes: the first vehicle element has leaderID (SUMO's native Parquet
    never has them: it cannot write those columns)."""
    if fcd_path.name.endswith(".parquet"):
        return any("leaderID" in c for c in pl.read_parquet_schema(fcd_path))
    try:
        with open(fcd_path, "rb") as f:
            gzipped = f.read(2) == b"\x1f\x8b"
        with (gzip.open if gzipped else open)(fcd_path, "rb") as f:
            head = f.read(1 << 16)
    except (OSError, EOFError, zlib.error):
        return True  # read_fcd reports the damaged file with its fix
    start = head.find(b"<vehicle ")
    end = head.find(b">", start)
    return start < 0 or b"leaderID=" in head[start:end if end > 0 else None]


def is_vehicle() -> pl.Expr:
    """A potential ego: a vType of a vehicle kind (not bicycle, pedestrian or an object class)."""
    return pl.col("kind").is_in(VEHICLE_KINDS)


def _island(keys: list[str], max_gap_frames: int) -> pl.Expr:
    """An id per run of frames of each key: a run goes on across at most ``max_gap_frames`` missing frames, the
    matcher's gap rule (docs/semantics.md, "gaps and jitter"), which a label follows like the matcher does."""
    step = pl.col("frame").diff().over(keys, order_by="frame")
    return (step.is_null() | (step - 1 > max_gap_frames)).cast(pl.Int64).cum_sum().over(keys, order_by="frame")


def _gap_frames(p: dict, dt: float) -> int:
    """max_gap in frames, floor(max_gap / dt), as docs/semantics.md counts it."""
    return math.floor(p["max_gap"] / dt + EPS)


def _islands(frames: pl.DataFrame, keys: list[str], max_gap_frames: int) -> pl.DataFrame:
    """Maximal runs of frames per key, bridging gaps of at most ``max_gap_frames``: start/end frame and t_s."""
    return (frames.with_columns(island=_island(keys, max_gap_frames))
            .group_by(*keys, "island")
            .agg(start_frame=pl.col("frame").min(), end_frame=pl.col("frame").max(),
                 start_s=pl.col("t_s").min(), end_s=pl.col("t_s").max()))


def _headway_ok(gap: str, speed: str, p: dict) -> pl.Expr:
    """gap / speed of the trailing vehicle within the scenario's time headway range (speed > 0)."""
    headway = pl.col(gap) / pl.col(speed)
    return ((pl.col(speed) > 0) & (headway >= p["min_distance_from_sut_in_time_units"] - EPS)
            & (headway <= p["max_distance_from_sut_in_time_units"] + EPS))


# ------------------------------------------------------------------------------------------- follower_vehicle

def follower_vehicle(rows: pl.DataFrame, p: dict, dt: float) -> pl.DataFrame:
    """The actor's FCD leader is the ego at a headway in range, in the same lane; islands cut at the ego's lane
    changes. Same lane as the spec means it ("drives behind the Ego in the same lane"): the actor's FCD lane is one
    the ego was on, in its current lane run, at most same_road_limit ago. SUMO's leader search alone follows the
    actor's route across a junction, so a car waiting on its approach would follow an ego that came from another
    approach and turned onto the exit the car will take."""
    egos = rows.filter(is_vehicle()).select(ego_id="vehicle_id", frame="frame", ego_run="lane_run")
    following = (
        rows.filter(pl.col("kind").is_in(p["kinds"]) & pl.col("leader_id").is_not_null()
                    & _headway_ok("leader_gap_m", "speed_mps", p))
        .select(ego_id="leader_id", actor_id="vehicle_id", frame="frame", t_s="t_s", lane_id="lane_id")
        .join(egos, on=["ego_id", "frame"])
    )
    ego_was_on = (rows.filter(is_vehicle())
                  .select(ego_id="vehicle_id", lane_id="lane_id", ego_run="lane_run", t_s="t_s",
                          ego_on_lane_s="t_s").sort("t_s"))
    same_lane = (following.sort("t_s")
                 .join_asof(ego_was_on, on="t_s", by=["ego_id", "lane_id", "ego_run"], strategy="backward",
                            check_sortedness=False)  # both sorted by t_s above, so within every group too
                 .filter(pl.col("t_s") - pl.col("ego_on_lane_s") <= p["same_road_limit"] + EPS))
    islands = _islands(same_lane, ["ego_id", "actor_id", "ego_run"], _gap_frames(p, dt))
    return islands.filter(pl.col("end_s") - pl.col("start_s") >= p["min_scenario_duration"] - EPS).select(
        "ego_id", "actor_id", "start_s", "end_s",
        source=pl.lit("fcd: actor's leaderID = ego, leaderGap / actor speed in range, actor on a lane the ego was "
                      "on within same_road_limit; cut at the ego's lanechange records"))


# ------------------------------------------------------------------------------------------------ sut_cut_out

def _window(changes: pl.DataFrame, frames: int, sign: int, first: int) -> pl.DataFrame:
    """One row per change and step k = 0..frames: frame = fc + first + sign * k."""
    return changes.with_columns(k=pl.int_ranges(0, frames + 1)).explode("k").with_columns(
        frame=pl.col("fc") + first + sign * pl.col("k"))


def _leading_run(grid: pl.DataFrame, ok: pl.Expr) -> pl.DataFrame:
    """Per change: how many steps from k = 0 on all satisfy ``ok`` (a missing row fails), and their t_s span."""
    flagged = grid.with_columns(ok=ok.fill_null(False).cast(pl.Int64)).with_columns(
        ok=pl.col("ok").cum_min().over("change_id", order_by="k"))
    return flagged.group_by("change_id").agg(
        steps=pl.col("ok").sum(), first_s=pl.col("t_s").filter(pl.col("ok") == 1).min(),
        last_s=pl.col("t_s").filter(pl.col("ok") == 1).max())


def _lane_on_edge(grid: pl.DataFrame, rows: pl.DataFrame, who: str, segment: str, edge: str,
                  name: str) -> pl.DataFrame:
    """For every (change_id, k) of ``grid``: the lane index vehicle ``who`` drove, or will drive, on ``edge``.

    On the same edge that is its own lane. Otherwise one of the two has crossed onto the next edge (or a
    junction's internal lane) first: take the nearest of the vehicle's own lane segments, up to
    ``_SEGMENT_REACH`` before or after ``segment``, that lies on ``edge`` (so a split or merge of lanes is
    resolved as the vehicle went).
    """
    segments = rows.select("vehicle_id", "lane_segment", "edge_id", "lane_index").unique(
        ["vehicle_id", "lane_segment"])
    offsets = pl.int_ranges(-_SEGMENT_REACH, _SEGMENT_REACH + 1)
    return (
        grid.filter(pl.col(segment).is_not_null() & pl.col(edge).is_not_null())
        .select("change_id", "k", who, segment, edge)
        .with_columns(offset=offsets).explode("offset")
        .join(segments, left_on=[who, pl.col(segment) + pl.col("offset")],
              right_on=["vehicle_id", "lane_segment"])
        .filter(pl.col("edge_id") == pl.col(edge))
        .sort(pl.col("offset").abs(), "offset")
        .unique(["change_id", "k"], keep="first")
        .select("change_id", "k", pl.col("lane_index").alias(name))
    )


def sut_cut_out(rows: pl.DataFrame, changes: pl.DataFrame, p: dict, dt: float) -> pl.DataFrame:
    """The ego follows its FCD leader A, changes lanes (a lanechange record), then drives beside A.

    Phase 1 ends at the frame before the record, phase 2 starts at the record's frame (SUMO records the change
    in the step the ego's front centre enters the new lane: its FCD lane there is already the new one).
    """
    vehicle_rows = rows.filter(is_vehicle())
    ego_at = vehicle_rows.select(ego_id="vehicle_id", frame="frame", e_leader="leader_id", e_gap="leader_gap_m",
                                 e_speed="speed_mps", e_run="lane_run", e_edge="edge_id", e_index="lane_index",
                                 e_segment="lane_segment", t_s="t_s")
    actor_at = rows.filter(pl.col("kind").is_in(p["kinds"])).select(
        actor_id="vehicle_id", frame="frame", a_run="lane_run", a_segment="lane_segment", a_edge="edge_id",
        a_index="lane_index")
    before = (
        changes.select(ego_id="vehicle_id", fc="frame", tc="t_s", from_lane="from_lane", to_lane="to_lane")
        .with_row_index("change_id")
        .join(ego_at.select("ego_id", "frame", actor_id="e_leader", run_before="e_run"),
              left_on=["ego_id", pl.col("fc") - 1], right_on=["ego_id", "frame"])
        .filter(pl.col("actor_id").is_not_null())
        .join(actor_at.select("actor_id", "frame", a_run_before="a_run"),
              left_on=["actor_id", pl.col("fc") - 1], right_on=["actor_id", "frame"])
    )
    max1 = math.floor(p["max_ego_on_same_lane_phase_duration"] / dt + EPS)
    phase1 = _leading_run(
        _window(before, max1, -1, -1).join(ego_at, on=["ego_id", "frame"], how="left"),
        (pl.col("e_leader") == pl.col("actor_id")) & (pl.col("e_run") == pl.col("run_before"))
        & _headway_ok("e_gap", "e_speed", p))
    max2 = math.floor(p["max_ego_on_side_of_npc_phase_duration"] / dt + EPS)
    grid2 = (_window(before, max2, 1, 0).join(ego_at, on=["ego_id", "frame"], how="left")
             .join(actor_at, on=["actor_id", "frame"], how="left"))
    # Beside: lane indices one apart on one edge, the actor's lane on the ego's edge or, when the actor never
    # drove it (the ego on a junction's internal lane, the actor already past it), the ego's on the actor's.
    grid2 = (grid2.join(_lane_on_edge(grid2, rows, "actor_id", "a_segment", "e_edge", "a_index_on_e_edge"),
                        on=["change_id", "k"], how="left")
             .join(_lane_on_edge(grid2, rows, "ego_id", "e_segment", "a_edge", "e_index_on_a_edge"),
                   on=["change_id", "k"], how="left"))
    beside = pl.coalesce((pl.col("a_index_on_e_edge") - pl.col("e_index")).abs(),
                         (pl.col("e_index_on_a_edge") - pl.col("a_index")).abs()) == 1
    phase2 = _leading_run(grid2, (pl.col("e_run") == pl.col("run_before") + 1)
                          & (pl.col("a_run") == pl.col("a_run_before")) & beside)
    min1, min2 = p["min_ego_on_same_lane_phase_duration"], p["min_ego_on_side_of_npc_phase_duration"]
    return (
        before.join(phase1, on="change_id").join(phase2, on="change_id", suffix="_2")
        .filter(((pl.col("steps") - 1) * dt >= min1 - EPS) & ((pl.col("steps_2") - 1) * dt >= min2 - EPS))
        .select("ego_id", "actor_id", start_s="first_s", end_s="last_s_2",
                source=pl.format("lanechange-output: {} -> {} at {} s; fcd: ego's leaderID before, lanes after",
                                 "from_lane", "to_lane", pl.col("tc").round(3)))
    )


# ---------------------------------------------------------------------------------- cyclist_close_to_moving_sut

def box_corners(x_m: np.ndarray, y_m: np.ndarray, heading_rad: np.ndarray, length_m: np.ndarray,
                width_m: np.ndarray) -> np.ndarray:
    """(n, 4, 2) corners, counter-clockwise, of boxes given by centre, heading and size."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    lon = np.array([1, -1, -1, 1])[None, :] * (length_m / 2)[:, None]
    lat = np.array([1, 1, -1, -1])[None, :] * (width_m / 2)[:, None]
    return np.stack([x_m[:, None] + lon * c[:, None] - lat * s[:, None],
                     y_m[:, None] + lon * s[:, None] + lat * c[:, None]], axis=-1)


def box_distance_m(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Closest distance between convex quadrilaterals ``a`` and ``b`` ((n, 4, 2) corners each), 0 on overlap.

    Overlap by the separating-axis test on the edge normals of both; otherwise the least distance from a corner
    of one to an edge of the other (for two disjoint convex polygons the closest points include a corner).
    """
    def separated(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        edges = np.roll(p, -1, axis=1) - p
        normals = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)  # (n, 4, 2)
        pp = np.einsum("nkd,njd->nkj", normals, p)
        qq = np.einsum("nkd,njd->nkj", normals, q)
        return ((pp.max(axis=2) < qq.min(axis=2)) | (qq.max(axis=2) < pp.min(axis=2))).any(axis=1)

    def corner_to_edges(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        start = q[:, None, :, :]                               # (n, 1, 4, 2) edges of q
        edge = (np.roll(q, -1, axis=1) - q)[:, None, :, :]
        rel = p[:, :, None, :] - start                         # (n, 4 corners, 4 edges, 2)
        t = np.clip((rel * edge).sum(-1) / np.maximum((edge * edge).sum(-1), 1e-12), 0.0, 1.0)
        return np.linalg.norm(rel - t[..., None] * edge, axis=-1).min(axis=(1, 2))

    apart = separated(a, b) | separated(b, a)
    return np.where(apart, np.minimum(corner_to_edges(a, b), corner_to_edges(b, a)), 0.0)


def _with_boxes(rows: pl.DataFrame) -> pl.DataFrame:
    """Box centre and heading from SUMO's front bumper and navigation angle (0 = north, clockwise)."""
    heading = ((90.0 - pl.col("angle_deg")) * math.pi / 180.0)
    return rows.with_columns(heading_rad=heading).with_columns(
        xc_m=pl.col("x_m") - pl.col("length_m") / 2 * pl.col("heading_rad").cos(),
        yc_m=pl.col("y_m") - pl.col("length_m") / 2 * pl.col("heading_rad").sin(),
        reach_m=(pl.col("length_m") ** 2 + pl.col("width_m") ** 2).sqrt() / 2)


def cyclist_close_to_moving_sut(rows: pl.DataFrame, p: dict, dt: float) -> pl.DataFrame:
    """Ego at speed >= sut_minimal_speed with a cyclist's box within the distance band; pieces of at most
    max_phase_duration."""
    boxes = _with_boxes(rows)
    cols = ("vehicle_id", "frame", "t_s", "xc_m", "yc_m", "heading_rad", "length_m", "width_m", "reach_m")
    egos = boxes.filter(is_vehicle() & (pl.col("speed_mps") >= p["sut_minimal_speed"] - EPS)).select(cols)
    bikes = boxes.filter(pl.col("kind") == "cyclist").select(cols)
    if egos.is_empty() or bikes.is_empty():
        return pl.DataFrame(schema={k: LABEL_SCHEMA[k] for k in ("ego_id", "actor_id", "start_s", "end_s",
                                                                  "source")})
    # spatial hash: a pair can only be close when the centres are within the band plus both half diagonals
    cell_m = p["max_distance_from_cyclist"] + float(egos["reach_m"].max()) + float(bikes["reach_m"].max())
    cell = [(pl.col("xc_m") / cell_m).floor().cast(pl.Int64).alias("cx"),
            (pl.col("yc_m") / cell_m).floor().cast(pl.Int64).alias("cy")]
    near = pl.int_ranges(-1, 2)
    bikes = (bikes.with_columns(*cell).with_columns(dx=near).explode("dx").with_columns(dy=near).explode("dy")
             .with_columns(cx=pl.col("cx") + pl.col("dx"), cy=pl.col("cy") + pl.col("dy")).drop("dx", "dy"))
    pairs = (egos.with_columns(*cell).join(bikes, on=["frame", "cx", "cy"], suffix="_c")
             .filter(((pl.col("xc_m") - pl.col("xc_m_c")) ** 2 + (pl.col("yc_m") - pl.col("yc_m_c")) ** 2).sqrt()
                     <= p["max_distance_from_cyclist"] + pl.col("reach_m") + pl.col("reach_m_c")))

    def corners(suffix: str) -> np.ndarray:
        return box_corners(*(pairs[c + suffix].to_numpy() for c in ("xc_m", "yc_m", "heading_rad", "length_m",
                                                                    "width_m")))

    distance = box_distance_m(corners(""), corners("_c")) if pairs.height else np.zeros(0)
    close = pairs.with_columns(distance_m=pl.Series(distance, dtype=pl.Float64)).filter(
        (pl.col("distance_m") >= p["min_distance_from_cyclist"] - EPS)
        & (pl.col("distance_m") <= p["max_distance_from_cyclist"] + EPS)
    ).select(ego_id="vehicle_id", actor_id="vehicle_id_c", frame="frame", t_s="t_s")
    piece_frames = math.floor(p["max_phase_duration"] / dt + EPS) + 1
    keys = ["ego_id", "actor_id"]
    pieces = (close.with_columns(island=_island(keys, _gap_frames(p, dt)))
              .with_columns(piece=(pl.col("frame") - pl.col("frame").min().over(*keys, "island")) // piece_frames))
    return pieces.group_by(*keys, "island", "piece").agg(start_s=pl.col("t_s").min(), end_s=pl.col("t_s").max()
                                                         ).select(
        "ego_id", "actor_id", "start_s", "end_s",
        source=pl.lit("fcd x, y, angle + vType length, width: box distance in range; fcd speed of the ego"))


# ------------------------------------------------------------ unprotected_left_turn_with_yield_and_traffic_light

GREEN = ("G", "g")  # SUMO link states of a green light: priority green and permissive green (must yield)
LEFT_TURN_DIRS = ("l", "L")   # SUMO connection dir of a left (and partly left) turn


# load_signals' links and path_lanes
LINK_SCHEMA = {"link": pl.String, "tl": pl.String, "link_index": pl.Int64, "dir": pl.String, "from_edge": pl.String,
               "to_edge": pl.String, "total_m": pl.Float64, "shape": pl.List(pl.Float64)}
PATH_LANE_SCHEMA = {"link": pl.String, "lane_id": pl.String, "start_m": pl.Float64, "lane_length_m": pl.Float64,
                    "shape_length_m": pl.Float64}


def load_signals(folder: str | Path) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """(links, path_lanes, states) of a SUMO run folder, from its network and tls_states file.

    links: one per signalised connection (``tl`` and ``linkIndex`` set): link ("tl:index"), tl, link_index, dir,
    from_edge, to_edge, total_m (the summed ``length`` of its internal lanes: the path through the junction)
    and shape (its internal lanes' shapes joined, x/y pairs).
    path_lanes: every lane a vehicle on a link's path can be on, with the front offset from the link's junction
    start at lane position 0 (``start_m``; the lane position is added): the incoming edge's lanes (start_m =
    -length, so the stop line is 0), the internal lanes in order (0, then the lengths before), the outgoing
    edge's lanes (total_m). lane_length_m and shape_length_m of internal lanes map shape to lane positions.
    states: tl, t_s, state (SUMO's link-state string, character i = link i), one row per record.
    Empty frames when the network has no signalised connection.
    """
    folder = Path(folder)
    net_path = run_file(folder, ("*.net.xml", "*.net.xml.gz"), "SUMO network",
                        "copy the network the run used (e.g. network.net.xml.gz) into the folder.")
    root = parse_sumo_xml(net_path, "net")
    lanes = {lane.get("id"): (float(lane.get("length", "nan")), lane.get("shape", ""))
             for edge in root.iter("edge") for lane in edge.iter("lane")}
    edge_lanes: dict[str, list[str]] = {}
    for edge in root.iter("edge"):
        edge_lanes[edge.get("id", "")] = [lane.get("id") for lane in edge.iter("lane")]
    # an internal lane's onward connection: (its edge, lane index) -> the next internal lane (via) or None
    onward = {(c.get("from"), c.get("fromLane")): c.get("via") for c in root.iter("connection")
              if c.get("from", "").startswith(":")}
    link_rows, lane_rows = [], []
    for c in root.iter("connection"):
        if not c.get("tl") or c.get("linkIndex") in (None, "-1") or not c.get("via"):
            continue
        link = f"{c.get('tl')}:{c.get('linkIndex')}"
        chain, via = [], c.get("via")
        while via and via in lanes and via not in chain:
            chain.append(via)
            edge, _, index = via.rpartition("_")
            via = onward.get((edge, index))
        offset, coords = 0.0, []
        for lane in chain:
            length, shape = lanes[lane]
            xy = shape_coords(shape)
            coords.append(xy)
            lane_rows.append((link, lane, offset, length, float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())))
            offset += length
        lane_rows += [(link, lane, -lanes[lane][0], None, None) for lane in edge_lanes.get(c.get("from"), [])]
        lane_rows += [(link, lane, offset, None, None) for lane in edge_lanes.get(c.get("to"), [])]
        link_rows.append((link, c.get("tl"), int(c.get("linkIndex")), c.get("dir", ""), c.get("from"), c.get("to"),
                          offset, np.concatenate(coords).ravel().tolist()))
    links = pl.DataFrame(link_rows, orient="row", schema=LINK_SCHEMA)
    path_lanes = pl.DataFrame(lane_rows, orient="row", schema=PATH_LANE_SCHEMA)
    tls_path = run_file(folder, ("tls_states*.xml", "tls_states*.xml.gz"), "signal state", "", required=False)
    if links.height and tls_path is None:
        raise InputError(f"{folder}: the network has traffic lights but the folder has no tls_states file. Fix: "
                         "run sumo with an additional file holding <timedEvent type=\"SaveTLSStates\" "
                         "source=\"TLS_ID\" dest=\"tls_states.xml.gz\"/> (logiq-sql simulate junction does).")
    states = (xml_records(tls_path, "tlsState", ("time", "id", "state"), "</tlsStates>").select(
        tl="id", t_s=pl.col("time").cast(pl.Float64), state="state") if tls_path is not None
        else pl.DataFrame(schema={"tl": pl.String, "t_s": pl.Float64, "state": pl.String}))
    return links, path_lanes, states


def conflict_zones(links: pl.DataFrame, path_lanes: pl.DataFrame, ego_widths: list[float],
                   actor_widths: list[float]) -> pl.DataFrame:
    """Where the path of a left turn (ego link) crosses the path of a link from another incoming edge.

    Each path is its internal lanes' centre line swept by half a box width (flat ends); the conflict is the
    intersection of the two areas (shapely, from the network's own lane shapes). Its extent along each path,
    [enter, leave], is the least and greatest projection of its vertices, in SUMO lane-position metres from the
    link's junction start. One row per (ego link, actor link, ego width, actor width) whose areas overlap.
    """
    schema = {"link": pl.String, "link_f": pl.String, "width_m": pl.Float64, "width_m_f": pl.Float64,
              "enter_m": pl.Float64, "leave_m": pl.Float64, "enter_m_f": pl.Float64, "leave_m_f": pl.Float64}
    paths = links.with_row_index("path").select("path", "link", "dir", "from_edge", "shape")
    pairs = (paths.filter(pl.col("dir").is_in(LEFT_TURN_DIRS))
             .join(paths.drop("dir"), how="cross", suffix="_f").filter(pl.col("from_edge") != pl.col("from_edge_f"))
             .join(pl.DataFrame({"width_m": ego_widths}, schema={"width_m": pl.Float64}), how="cross")
             .join(pl.DataFrame({"width_m_f": actor_widths}, schema={"width_m_f": pl.Float64}), how="cross"))
    if pairs.is_empty():
        return pl.DataFrame(schema=schema)
    flat = paths["shape"].to_list()
    lines = shapely.linestrings(np.concatenate([np.reshape(s, (-1, 2)) for s in flat]),
                                indices=np.repeat(np.arange(len(flat)), [len(s) // 2 for s in flat]))
    e, f = pairs["path"].to_numpy(), pairs["path_f"].to_numpy()
    area = shapely.intersection(shapely.buffer(lines[e], pairs["width_m"].to_numpy() / 2, cap_style="flat"),
                                shapely.buffer(lines[f], pairs["width_m_f"].to_numpy() / 2, cap_style="flat"))
    xy, pair = shapely.get_coordinates(area, return_index=True)
    points = shapely.points(xy)
    along = pl.DataFrame({"pair": pair, "d": shapely.line_locate_point(lines[e[pair]], points),
                          "d_f": shapely.line_locate_point(lines[f[pair]], points)})
    # shape metres -> lane-position metres, lane by lane along the path (SUMO's length may differ from the shape's)
    internal = (path_lanes.filter(pl.col("lane_length_m").is_not_null())
                .with_columns(shape_start_m=pl.col("shape_length_m").cum_sum().over("link", order_by="start_m")
                              - pl.col("shape_length_m"),
                              scale=pl.col("lane_length_m") / pl.col("shape_length_m").clip(lower_bound=1e-9))
                .select("link", "shape_start_m", "start_m", "scale").sort("shape_start_m"))

    def lane_m(d: str, link: str) -> pl.DataFrame:
        return (along.join(pairs.with_row_index("pair").select("pair", link=link), on="pair").sort(d)
                .join_asof(internal, left_on=d, right_on="shape_start_m", by="link", strategy="backward",
                           check_sortedness=False)
                .select("pair", m=pl.col("start_m") + (pl.col(d) - pl.col("shape_start_m")) * pl.col("scale")))

    ego_m = lane_m("d", "link").group_by("pair").agg(enter_m=pl.col("m").min(), leave_m=pl.col("m").max())
    foe_m = lane_m("d_f", "link_f").group_by("pair").agg(enter_m_f=pl.col("m").min(), leave_m_f=pl.col("m").max())
    return (pairs.with_row_index("pair").with_columns(area_m2=pl.Series(shapely.area(area)))
            .filter(pl.col("area_m2") > 0).join(ego_m, on="pair").join(foe_m, on="pair").select(*schema))


def on_paths(rows: pl.DataFrame, links: pl.DataFrame, path_lanes: pl.DataFrame) -> pl.DataFrame:
    """The rows of every vehicle that went onto a signalised link, on the lanes of that link's path, with its
    link and front_m / centre_m: the front's (centre's) offset from the junction start along the path.

    A vehicle's link is that of the first internal lane of a signalised path it was on. The front is SUMO's
    lane position (the point the junction offsets measure, docs/semantics.md); the centre is front - length / 2.
    """
    internal = path_lanes.filter(pl.col("lane_length_m").is_not_null())
    first = (rows.join(internal.select("lane_id", "link"), on="lane_id")
             .group_by("vehicle_id").agg(pl.col("link").sort_by("frame").first()))
    outer = path_lanes.filter(pl.col("lane_length_m").is_null()).select("link", "lane_id", outer_m="start_m")
    return (rows.join(first, on="vehicle_id")
            .join(outer, on=["link", "lane_id"], how="left")
            .join(internal.select("lane_id", inner_m="start_m"), on="lane_id", how="left")
            .with_columns(front_m=pl.coalesce("inner_m", "outer_m") + pl.col("lane_pos_m"))
            .filter(pl.col("front_m").is_not_null())
            .with_columns(centre_m=pl.col("front_m") - pl.col("length_m") / 2)
            .join(links.select("link", "tl", "link_index", "dir", "from_edge", "total_m"), on="link")
            .drop("inner_m", "outer_m"))


def ego_in_frames(pairs: pl.DataFrame, paths: pl.DataFrame) -> pl.DataFrame:
    """The first frame the ego's box reaches each conflict: its front passes enter_m."""
    return (pairs.select("ego_id", "enter_m").unique()
            .join(paths.select(ego_id="vehicle_id", frame="frame", front_m="front_m"), on="ego_id")
            .filter(pl.col("front_m") >= pl.col("enter_m") - EPS)
            .group_by("ego_id", "enter_m").agg(ego_in_frame=pl.col("frame").min()))


def actor_out_frames(pairs: pl.DataFrame, paths: pl.DataFrame) -> pl.DataFrame:
    """The first frame the actor's box has left each conflict: its rear (front - length) is past leave_m_f."""
    return (pairs.select("actor_id", "leave_m_f", "length_m_f").unique()
            .join(paths.select(actor_id="vehicle_id", frame="frame", front_m="front_m"), on="actor_id")
            .filter(pl.col("front_m") - pl.col("length_m_f") > pl.col("leave_m_f") + EPS)
            .group_by("actor_id", "leave_m_f", "length_m_f").agg(actor_out_frame=pl.col("frame").min()))


def actor_in_frames(pairs: pl.DataFrame, paths: pl.DataFrame) -> pl.DataFrame:
    """The first frame the actor's box reaches each conflict: its front passes enter_m_f."""
    return (pairs.select("actor_id", "enter_m_f").unique()
            .join(paths.select(actor_id="vehicle_id", frame="frame", front_m="front_m"), on="actor_id")
            .filter(pl.col("front_m") >= pl.col("enter_m_f") - EPS)
            .group_by("actor_id", "enter_m_f").agg(actor_in_frame=pl.col("frame").min()))


def unprotected_left_turn_with_yield_and_traffic_light(rows: pl.DataFrame, links: pl.DataFrame,
                                                        path_lanes: pl.DataFrame, states: pl.DataFrame,
                                                        p: dict, dt: float) -> pl.DataFrame:
    """The ego, turning left (connection dir l/L), is stopped on green near its junction start while the actor,
    from another incoming edge, approaches (near its own junction start, or past it and not yet at the ego's
    path) to cross the ego's path; the actor
    clears the crossing before the ego reaches it, then the ego turns. From the ego's first such frame to its
    last frame inside the junction."""
    out_schema = {k: LABEL_SCHEMA[k] for k in ("ego_id", "actor_id", "start_s", "end_s", "source")}
    if links.is_empty():
        return pl.DataFrame(schema=out_schema)
    paths = on_paths(rows, links, path_lanes)
    lo, hi = p["min_offset_from_junction_start"] - EPS, p["max_offset_from_junction_start"] + EPS
    near = pl.col("front_m").is_between(lo, hi)
    light = (states.with_columns(frame=(pl.col("t_s") / dt).round().cast(pl.Int64)).drop("t_s")
             .unique(["tl", "frame"], keep="last").sort("frame"))
    # the ego's frames near its junction start on green (stopped or not: it stops, then gives the right of way)
    stops = (paths.filter(is_vehicle() & pl.col("dir").is_in(LEFT_TURN_DIRS) & near
                          & (pl.col("front_m") >= -p["max_offset_from_traffic_light"] - EPS)
                          & (pl.col("front_m") < pl.col("total_m")))
             .sort("frame").join_asof(light, on="frame", by="tl", strategy="backward", check_sortedness=False)
             .filter(pl.col("state").str.slice(pl.col("link_index"), 1).is_in(GREEN))
             .select(ego_id="vehicle_id", frame="frame", t_s="t_s", link="link", from_edge="from_edge",
                     width_m="width_m", stopped=pl.col("speed_mps") <= p["stopping_car_speed_limit"] + EPS))
    # the actor approaching: its front near its junction start, or past it and not yet at the ego's path (the
    # conflict; tested below, once the conflict is known): on a skewed or large junction the car the ego stands
    # for may be more than max_offset_from_junction_start into the junction
    foes = paths.filter(pl.col("kind").is_in(p["kinds"]) & (pl.col("front_m") >= lo)
                        & (near | (pl.col("front_m") < pl.col("total_m") + pl.col("length_m")))).select(
        actor_id="vehicle_id", frame="frame", link_f="link", from_edge_f="from_edge", width_m_f="width_m",
        length_m_f="length_m", front_m_f="front_m")
    zones = conflict_zones(links, path_lanes, stops["width_m"].unique().to_list(),
                           foes["width_m_f"].unique().to_list())
    pairs = (stops.join(foes, on="frame").filter((pl.col("ego_id") != pl.col("actor_id"))
                                                 & (pl.col("from_edge") != pl.col("from_edge_f")))
             .join(zones, on=["link", "link_f", "width_m", "width_m_f"]))
    # the ego's box reaches the conflict when its front passes enter_m; the actor's has left it when its rear
    # (front - length) is past leave_m_f: the first frame of each
    ego_in, actor_out, actor_in = (ego_in_frames(pairs, paths), actor_out_frames(pairs, paths),
                                   actor_in_frames(pairs, paths))
    inside = (paths.filter(is_vehicle() & pl.col("dir").is_in(LEFT_TURN_DIRS))
              .group_by(ego_id="vehicle_id")
              .agg(end_s=pl.col("t_s").filter((pl.col("front_m") >= -EPS)
                                              & (pl.col("front_m") < pl.col("total_m"))).max(),
                   exited=(pl.col("front_m") >= pl.col("total_m")).any()))
    waiting = (pairs.join(ego_in, on=["ego_id", "enter_m"]).join(actor_out, on=["actor_id", "leave_m_f", "length_m_f"])
               .join(actor_in, on=["actor_id", "enter_m_f"])
               .filter((pl.col("frame") < pl.col("ego_in_frame"))
                       & (pl.col("actor_out_frame") <= pl.col("ego_in_frame"))
                       & ((pl.col("front_m_f") <= hi) | (pl.col("frame") < pl.col("actor_in_frame")))))
    # the ego waits until the actor is in the junction: the actor's front is past its junction start within
    # the run of waiting frames or at most max_gap after it (a run that ends earlier is no wait for this actor;
    # the scenario's sequence bridges max_gap between one phase and the next, as when the light turns amber
    # while the actor reaches its stop line); the run
    # counts from the ego's first stop in it (it stops, then may pull forward while it gives way)
    keys = ["ego_id", "actor_id", "link", "link_f"]
    runs = (waiting.with_columns(island=_island(keys, _gap_frames(p, dt)))
            .group_by(*keys, "island")
            .agg(start_frame=pl.col("frame").filter("stopped").min(), end_frame=pl.col("frame").max(),
                 start_s=pl.col("t_s").filter("stopped").min())
            .drop_nulls("start_frame"))
    entered = (runs.select(*keys, "island", "start_frame", "end_frame")
               .join(paths.select(actor_id="vehicle_id", frame="frame", front_m_f="front_m"), on="actor_id")
               .filter(pl.col("frame").is_between("start_frame", pl.col("end_frame") + 1 + _gap_frames(p, dt))
                       & (pl.col("front_m_f") >= -EPS))
               .select(*keys, "island").unique())
    # the turn follows the crossing: E sets off (the step after its last stop before its box reaches the
    # conflict) at the latest max_gap after A's front is max_offset_from_junction_end past its junction end
    stood = paths.filter(pl.col("speed_mps") <= p["stopping_car_speed_limit"] + EPS).select(
        ego_id="vehicle_id", stop_frame="frame")
    set_off = (waiting.select(*keys, "ego_in_frame").unique().join(stood, on="ego_id")
               .filter(pl.col("stop_frame") < pl.col("ego_in_frame"))
               .group_by(keys).agg(set_off=pl.col("stop_frame").max() + 1))
    crossed = (paths.filter(pl.col("front_m") <= pl.col("total_m") + p["max_offset_from_junction_end"] + EPS)
               .group_by(actor_id="vehicle_id").agg(crossed_frame=pl.col("frame").max()))
    # ... or A is the last actor to leave E's path of those whose front had reached it when E set off (E sets off
    # as the car it waited for clears its path), or left it at most max_gap before that one (phase 3 lasts until
    # the set-off then). Over every vehicle of kinds from another entry that crossed E's path first, whether or
    # not E stood for it on green: when the last one came through in the amber, E waited for it, not for the one
    # before it
    egos = stops.select("ego_id", "link", "from_edge", "width_m").unique()
    crossers = (egos.join(paths.filter(pl.col("kind").is_in(p["kinds"])).select(
        actor_id="vehicle_id", link_f="link", from_edge_f="from_edge", width_m_f="width_m",
        length_m_f="length_m").unique(), how="cross")
        .filter((pl.col("ego_id") != pl.col("actor_id")) & (pl.col("from_edge") != pl.col("from_edge_f"))))
    every_zone = conflict_zones(links, path_lanes, egos["width_m"].unique().to_list(),
                                crossers["width_m_f"].unique().to_list())
    crossings = crossers.join(every_zone, on=["link", "link_f", "width_m", "width_m_f"])
    outs = (crossings.join(ego_in_frames(crossings, paths), on=["ego_id", "enter_m"])
            .join(actor_out_frames(crossings, paths), on=["actor_id", "leave_m_f", "length_m_f"])
            .join(actor_in_frames(crossings, paths), on=["actor_id", "enter_m_f"])
            .filter(pl.col("actor_out_frame") <= pl.col("ego_in_frame"))
            .join(stood, on="ego_id").filter(pl.col("stop_frame") < pl.col("ego_in_frame"))
            .group_by(*keys, "actor_out_frame", "actor_in_frame").agg(set_off=pl.col("stop_frame").max() + 1))
    # E's set-off on its turn is its latest over those actors: an E that rolls into the junction behind one car
    # and stands there for the oncoming ones sets off once, after the last stand
    last = (outs.filter(pl.col("actor_in_frame") <= pl.col("set_off")).group_by("ego_id")
            .agg(last_out=pl.col("actor_out_frame").max(), turn_set_off=pl.col("set_off").max()))
    turns = (set_off.join(crossed, on="actor_id")
             .join(outs.select(*keys, "actor_out_frame"), on=keys).join(last, on="ego_id", how="left")
             .filter((pl.coalesce("turn_set_off", "set_off") <= pl.col("crossed_frame") + 1 + _gap_frames(p, dt))
                     | (pl.col("actor_out_frame") >= pl.col("last_out") - _gap_frames(p, dt)))
             .select(keys))
    return (
        runs.join(entered, on=[*keys, "island"]).join(turns, on=keys)
        .group_by(keys).agg(start_s=pl.col("start_s").min())
        .join(inside.filter("exited"), on="ego_id")
        .filter(pl.col("end_s") >= pl.col("start_s") - EPS)
        .select("ego_id", "actor_id", "start_s", "end_s",
                source=pl.format("net: ego link {} (left) crosses actor link {} (internal lane shapes); "
                                 "tls_states: green; fcd: lane, pos, speed", "link", "link_f"))
    )


# --------------------------------------------------------------------------------------------------- entry

def label_sumo(run_dir: str | Path, scenarios: list[str] | None = None,
               overrides: dict[str, str] | None = None) -> pl.DataFrame:
    """Labels (``LABEL_SCHEMA``) of ``scenarios`` (default all of ``SCENARIOS``) in one SUMO run folder.

    Every vehicle of the run is a potential ego; drive_id is the folder name, as ``ingest sumo`` names it.
    """
    values = scenario_values(list(scenarios or SCENARIOS), overrides)
    drive_id, dt, rows, changes = load_run(run_dir)
    found = []
    for name, p in values.items():
        if name == "follower_vehicle":
            labels = follower_vehicle(rows, p, dt)
        elif name == "sut_cut_out":
            labels = sut_cut_out(rows, changes, p, dt)
        elif name == "cyclist_close_to_moving_sut":
            labels = cyclist_close_to_moving_sut(rows, p, dt)
        else:
            links, path_lanes, states = load_signals(run_dir)
            labels = unprotected_left_turn_with_yield_and_traffic_light(rows, links, path_lanes, states, p, dt)
        # an episode shorter than max_gap is no event (docs/semantics.md, "gaps and jitter": the matcher keeps
        # no shorter match)
        labels = labels.filter(pl.col("end_s") - pl.col("start_s") >= p["max_gap"] - EPS)
        found.append(labels.select(pl.lit(drive_id).alias("drive_id"), pl.lit(name).alias("scenario"), pl.all()))
    return pl.concat(found).cast(LABEL_SCHEMA).select(*LABEL_SCHEMA).sort(
        "drive_id", "scenario", "ego_id", "actor_id", "start_s")


def label_runs(paths: list[str | Path], scenarios: list[str] | None = None,
               overrides: dict[str, str] | None = None) -> pl.DataFrame:
    """Labels of every SUMO run folder at or under ``paths`` (one drive each; drive ids must be unique)."""
    folders = [f for p in paths for f in run_folders(p)]
    names = [f.name for f in folders]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"two run folders are both named '{twice[0]}' (the drive id). Fix: rename one.")
    return pl.concat([label_sumo(f, scenarios, overrides) for f in folders])
