"""Argoverse 2 (AV2): sensor-dataset logs and motion-forecasting scenarios; one folder is one drive.

Folders
    A *sensor log* folder holds ``annotations.feather`` (or ``annotations_with_ego.feather``, preferred when both are
    there), ``city_SE3_egovehicle.feather`` and ``map/log_map_archive_*.json``. A *motion-forecasting* folder holds
    ``scenario_<id>.parquet`` and ``log_map_archive_<id>.json``. ``log_folders`` finds every such folder at or under a
    path (sorted); a file stands for its folder. drive_id = map_id = the folder's log id (sensor) or the scenario's
    ``scenario_id`` (forecasting; the file name's id if the column is absent): each drive carries its own map
    archive. dt_s = 0.1. Licence: Argoverse 2 (Argo AI), CC BY-NC-SA 4.0, non-commercial (``ATTRIBUTION``).

Sensor logs: from the ego-vehicle frame to the city frame
    AV2 boxes are in the ego-vehicle frame of their timestamp (x forward, y left, z up). For every annotation row the
    ego pose ``city_SE3_egovehicle`` nearest in time is taken (``np.searchsorted`` over the sorted pose stamps; the
    pose stream runs at ~170 Hz and, in the bundled logs, holds every annotation stamp exactly). Rows whose nearest
    pose is more than ``POSE_MAX_GAP_NS`` (50 ms) away are dropped and counted. Then, with rotation matrices from the
    normalised quaternions (qw, qx, qy, qz), ``city_R_obj = city_R_ego @ ego_R_obj`` and
    ``city_t_obj = city_R_ego @ ego_t_obj + city_t_ego`` (full 3D, so the ego's roll and pitch are respected);
    x_m / y_m = the first two components of ``city_t_obj``, heading_rad = yaw of ``city_R_obj``
    (``atan2(R[1, 0], R[0, 0])``). length_m / width_m = the box's. speed_mps and accel_mps2 are NULL: the staging
    query derives them from the positions (central differences over the real time stamps).

    Time: t_s = (timestamp_ns - first annotation timestamp) / 1e9, kept as measured (AV2 stamps jitter by a few
    ms around 10 Hz); frame = round(t_s / 0.1). Two rows of one actor in one frame: the one nearer to frame * 0.1 s
    is kept, the other dropped and counted.

    The ego becomes the actor ``ego`` (is_ego, kind vehicle), one row per annotation timestamp, from the nearest
    pose. AV2's ego-vehicle frame has its origin at the centre of the rear axle (the calibration puts the roof lidar
    1.35 m and the front cameras 1.63 m ahead of it), while ``tracks`` holds box centres: the ego's centre is put
    ``EGO_CENTRE_AHEAD_M`` = 1.425 m ahead of the origin along its heading, half the 2.85 m wheelbase of the Ford
    Fusion Hybrid AV2 was recorded with (assumes equal overhangs; uncertain by about 0.1 m). Size: length 4.877 m,
    width 2.0 m, the box of the ``EGO_VEHICLE`` rows of ``annotations_with_ego.feather`` (which are read from the file
    when present; those rows place the box at the frame origin, which is not followed here). ``EGO_VEHICLE`` rows are
    otherwise not actors: the ego comes from the pose file.

    rows_read = annotation rows other than ``EGO_VEHICLE`` + one ego sample per annotation timestamp.

Sensor categories -> evaluation_object_kind (``SENSOR_KINDS``)
    ======================================================  ============  ==========================================
    AV2 category                                            kind          why
    ======================================================  ============  ==========================================
    REGULAR_VEHICLE, LARGE_VEHICLE                          vehicle       cars, vans, pickups; RVs, large vans
    BOX_TRUCK, TRUCK, TRUCK_CAB                             truck         AV2's truck classes (a cab without trailer)
    VEHICULAR_TRAILER                                       trailer       towed, non-motorised
    MESSAGE_BOARD_TRAILER, TRAFFIC_LIGHT_TRAILER            trailer       a sign or light mounted on a trailer: the
                                                                          trailer is what occupies the road
    BUS, SCHOOL_BUS, ARTICULATED_BUS                        bus
    RAILED_VEHICLE                                          bus           trams and trolleys share the street with
                                                                          bus-like size; no rail kind in the spec
    MOTORCYCLE, MOTORCYCLIST                                motorcycle    (a ridden motorcycle: see below)
    BICYCLIST                                               cyclist       person riding a bicycle
    WHEELED_RIDER                                           cyclist       person riding a scooter, skateboard, ...:
                                                                          moves like a cyclist, not a pedestrian
    BICYCLE, WHEELED_DEVICE                                 object        the device alone (parked); when ridden its
                                                                          rider is the actor (see below)
    PEDESTRIAN, WHEELCHAIR, STROLLER, OFFICIAL_SIGNALER     person        people on foot or pushed; a signaler is a
                                                                          person directing traffic
    DOG, ANIMAL                                             animal
    SIGN, STOP_SIGN, MOBILE_PEDESTRIAN_CROSSING_SIGN        sign          (``MOBILE_PEDESTRIAN_SIGN``, the name in
                                                                          the AV2 guide, is read the same way)
    BOLLARD, CONSTRUCTION_CONE, CONSTRUCTION_BARREL         object        static road furniture
    EGO_VEHICLE                                             (the ego)     see above
    ======================================================  ============  ==========================================

    AV2 annotates a rider and its vehicle as two boxes. One road user must be one actor, so at each timestamp a
    BICYCLE (WHEELED_DEVICE) whose centre lies within ``RIDER_MATCH_M`` (1.0 m) of a BICYCLIST (WHEELED_RIDER) is
    dropped as the rider's vehicle (the rider is the cyclist), and a MOTORCYCLIST within 1.0 m of a MOTORCYCLE is
    dropped as that motorcycle's rider (the motorcycle's box is the vehicle's). Those rows are counted in
    rows_rejected with the reason. A category not in the table is not guessed: its rows are dropped, counted in
    rows_rejected and named in reject_reason.

Motion-forecasting scenarios
    One row per ``(track_id, timestep)``: frame = timestep, t_s = timestep * 0.1, x_m / y_m = position_x / _y,
    heading_rad = heading, speed_mps = velocity projected on the heading (vx cos h + vy sin h), accel_mps2 NULL
    (derived). Every row is kept, ``observed`` or not: ``observed`` only splits the 5 s history (timesteps 0-49)
    from the 6 s future (50-109) that a forecaster must predict; both are recorded tracks. track ``AV`` is the ego
    (ego_actor_id ``AV``, kind vehicle, the ego size above, its centre moved ``EGO_CENTRE_AHEAD_M`` along its
    heading like the sensor ego, assuming the AV track is the ego-vehicle pose). Other actors have no size (NULL:
    the ingest fills the kind's default). object_type -> kind (``FORECASTING_KINDS``): vehicle -> vehicle,
    bus -> bus, motorcyclist -> motorcycle, cyclist -> cyclist, pedestrian -> person, riderless_bicycle -> object,
    static / background / construction / unknown -> object. Another object_type: dropped and counted as above.
    Rows with a non-finite position or heading are dropped and counted.

Map (``map_id`` = ``drive_id``)
    lanes: one row per ``lane_segments`` entry. polygon = left_lane_boundary followed by the reversed
    right_lane_boundary (x, y), repaired with ``shapely.make_valid`` only when invalid (largest part), snapped to the
    1e-4 m grid the WKT is written on. centerline = pointwise midpoints of the two boundaries after resampling both
    by arc length to the larger point count, in driving direction (AV2 boundaries run in driving direction); the
    ``centerline`` key of forecasting archives is not used, so both kinds of archive give the same geometry.
    lane_type = AV2 lane_type (VEHICLE, BIKE, BUS). left/right_lane_id = left/right_neighbor_id when that id is a
    lane of the archive (else NULL); ``*_same_direction`` = the neighbour's centre-line direction, at its point
    nearest to the midpoint of this lane's centre line, is within 90 degrees of this lane's direction there (AV2
    neighbours may be opposite-direction lanes). speed_limit_mps NULL (AV2 maps have none).

    lane_successors: ``successors`` of each segment, plus the pairs implied by ``predecessors``, both only when
    the other lane is in the archive (archives are cropped to the log's area: successors leaving it are dropped).
    turn NULL: AV2 does not say; the matching derives turns from the heading change.

    junctions: AV2 has no junction objects, only ``is_intersection`` per lane segment. The polygons of the
    intersection lanes are grown by ``JUNCTION_JOIN_M`` (5 cm, mitred) so that lanes that touch or nearly touch
    connect, united (``shapely.union_all``), and every connected part is one junction: polygon = that part (hence
    5 cm larger than its lanes), junction_id = ``"j"`` + the smallest lane id in it; each intersection lane's
    junction_id = the part containing it. Non-intersection lanes have junction_id NULL.

    traffic_lights / traffic_light_states: none. AV2 maps have no traffic lights. Pedestrian crossings and drivable
    areas have no canonical table and are not read.

Errors
    A missing annotations, pose, scenario or map file, several map archives in one log, an unreadable or malformed
    feather / parquet / JSON file, or missing columns raise ``InputError`` naming the file and the fix; ``ingest``
    records such a log as a rejected drive.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import shapely

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.base import DriveData

ATTRIBUTION = "Argoverse 2 (Argo AI), CC BY-NC-SA 4.0, non-commercial"

DT_S = 0.1
POSE_MAX_GAP_NS = 50_000_000  # an annotation further than this from every ego pose is dropped
EGO_ACTOR_ID = "ego"
EGO_LENGTH_M, EGO_WIDTH_M = 4.877, 2.0  # the EGO_VEHICLE box of annotations_with_ego.feather
EGO_CENTRE_AHEAD_M = 1.425  # box centre ahead of the ego-vehicle frame origin (rear axle): half the wheelbase
RIDER_MATCH_M = 1.0  # a rider and its vehicle: centres this close at one timestamp
JUNCTION_JOIN_M = 0.05  # intersection lanes closer than twice this join into one junction
DIRECTION_STEP_M = 0.5  # direction of a centre line from the points this far before and after
WKT_GRID_M = 1e-4
WKT_DIGITS = 4

POSE_FILE = "city_SE3_egovehicle.feather"
ANNOTATION_FILES = ("annotations_with_ego.feather", "annotations.feather")
EGO_CATEGORY = "EGO_VEHICLE"

SENSOR_KINDS: dict[str, str] = {
    "REGULAR_VEHICLE": "vehicle", "LARGE_VEHICLE": "vehicle",
    "BOX_TRUCK": "truck", "TRUCK": "truck", "TRUCK_CAB": "truck",
    "VEHICULAR_TRAILER": "trailer", "MESSAGE_BOARD_TRAILER": "trailer", "TRAFFIC_LIGHT_TRAILER": "trailer",
    "BUS": "bus", "SCHOOL_BUS": "bus", "ARTICULATED_BUS": "bus", "RAILED_VEHICLE": "bus",
    "MOTORCYCLE": "motorcycle", "MOTORCYCLIST": "motorcycle",
    "BICYCLIST": "cyclist", "WHEELED_RIDER": "cyclist",
    "BICYCLE": "object", "WHEELED_DEVICE": "object",
    "PEDESTRIAN": "person", "WHEELCHAIR": "person", "STROLLER": "person", "OFFICIAL_SIGNALER": "person",
    "DOG": "animal", "ANIMAL": "animal",
    "SIGN": "sign", "STOP_SIGN": "sign", "MOBILE_PEDESTRIAN_CROSSING_SIGN": "sign", "MOBILE_PEDESTRIAN_SIGN": "sign",
    "BOLLARD": "object", "CONSTRUCTION_CONE": "object", "CONSTRUCTION_BARREL": "object",
}
# (category dropped, category it goes with): the dropped one is the same road user as the other
_RIDDEN = (("BICYCLE", "BICYCLIST"), ("WHEELED_DEVICE", "WHEELED_RIDER"), ("MOTORCYCLIST", "MOTORCYCLE"))

FORECASTING_KINDS: dict[str, str] = {
    "vehicle": "vehicle", "bus": "bus", "motorcyclist": "motorcycle", "cyclist": "cyclist", "pedestrian": "person",
    "riderless_bicycle": "object", "static": "object", "background": "object", "construction": "object",
    "unknown": "object",
}
FORECASTING_EGO = "AV"

_ANNOTATION_COLUMNS = ("timestamp_ns", "track_uuid", "category", "length_m", "width_m",
                       "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
_POSE_COLUMNS = ("timestamp_ns", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
_SCENARIO_COLUMNS = ("track_id", "object_type", "timestep", "position_x", "position_y", "heading",
                     "velocity_x", "velocity_y")


# ------------------------------------------------------------------------------------------------------ folders

def _is_marker(name: str) -> bool:
    return name == POSE_FILE or (name.startswith("annotations") and name.endswith(".feather")) or (
        name.startswith("scenario_") and name.endswith(".parquet"))


def _is_log(folder: Path) -> bool:
    return folder.is_dir() and any(f.is_file() and _is_marker(f.name) for f in folder.iterdir())


def log_folders(path: str | Path) -> list[Path]:
    """The AV2 log / scenario folders at or under ``path``, sorted (a file means its folder).

    A folder with no AV2 file is returned as it is, so that reading it says what is missing.
    """
    path = Path(path)
    if path.is_file():
        return [path.parent]
    if _is_log(path):
        return [path]
    found = sorted({f.parent for f in path.rglob("*") if f.is_file() and _is_marker(f.name)})
    return found or [path]


def read_av2(path: str | Path) -> Iterator[DriveData]:
    """Read every AV2 sensor log or motion-forecasting scenario at or under ``path``: one drive each."""
    for folder in log_folders(path):
        scenarios = sorted(folder.glob("scenario_*.parquet"))
        if len(scenarios) > 1:
            raise InputError(f"{folder}: {len(scenarios)} scenario_*.parquet files; a scenario folder holds one. "
                             "Fix: move the others into folders of their own.")
        yield _read_scenario(folder, scenarios[0]) if scenarios else _read_sensor_log(folder)


# ---------------------------------------------------------------------------------------------------- file io

def _read_table(path: Path, columns: tuple[str, ...], what: str) -> pl.DataFrame:
    try:
        df = pl.read_parquet(path) if path.suffix == ".parquet" else pl.read_ipc(path)
    except (pl.exceptions.PolarsError, OSError, ValueError) as exc:  # truncated, empty or not Arrow / Parquet
        raise InputError(
            f"{path}: not a readable {what} ({type(exc).__name__}: {exc}). "
            "Fix: copy the file again from the Argoverse 2 dataset; it must be complete."
        ) from None
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{path}: the {what} lacks column(s) {', '.join(missing)}. "
                         f"Fix: give an AV2 {what} (columns {', '.join(columns)}).")
    return df


def _map_archive(folder: Path) -> tuple[Path, dict]:
    files = sorted({f for p in ("map/log_map_archive_*.json", "log_map_archive_*.json") for f in folder.glob(p)
                    if f.is_file()})
    if not files:
        raise InputError(
            f"{folder}: no map archive (map/log_map_archive_*.json or log_map_archive_*.json). "
            "Fix: copy the log's map folder (sensor logs) or its log_map_archive json (forecasting) beside it."
        )
    if len(files) > 1:
        raise InputError(f"{folder}: {len(files)} map archives ({', '.join(f.name for f in files)}); a log has one. "
                         "Fix: keep only the log's own archive.")
    try:
        archive = json.loads(files[0].read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{files[0]}: not a readable JSON map archive ({exc}). "
                         "Fix: copy the file again from the Argoverse 2 dataset.") from None
    if not isinstance(archive, dict) or not isinstance(archive.get("lane_segments"), dict):
        raise InputError(f"{files[0]}: no 'lane_segments' object; not an AV2 map archive. "
                         "Fix: give the log's log_map_archive_*.json.")
    return files[0], archive


# ---------------------------------------------------------------------------------------------------- geometry

def _rotations(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of (n, 4) quaternions (w, x, y, z), normalised first."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def _yaw(r: np.ndarray) -> np.ndarray:
    return np.arctan2(r[:, 1, 0], r[:, 0, 0])


def _nearest(sorted_stamps: np.ndarray, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest of ``sorted_stamps`` for each stamp, and the gap (ns)."""
    hi = np.minimum(np.searchsorted(sorted_stamps, stamps), len(sorted_stamps) - 1)
    lo = np.maximum(hi - 1, 0)
    idx = np.where(np.abs(sorted_stamps[hi] - stamps) < np.abs(stamps - sorted_stamps[lo]), hi, lo)
    return idx, np.abs(stamps - sorted_stamps[idx])


def _q(df: pl.DataFrame) -> np.ndarray:
    return df.select("qw", "qx", "qy", "qz").to_numpy().astype(float)


def _t(df: pl.DataFrame) -> np.ndarray:
    return df.select("tx_m", "ty_m", "tz_m").to_numpy().astype(float)


# ---------------------------------------------------------------------------------------------------- tracks

def _frames(t_s: np.ndarray) -> np.ndarray:
    return np.rint(t_s / DT_S).astype(np.int64)


def _one_per_frame(tracks: pl.DataFrame) -> tuple[pl.DataFrame, int]:
    """Keep one row per (actor, frame): the one nearest to frame * dt."""
    kept = (tracks.with_columns(_off=(pl.col("t_s") - pl.col("frame") * DT_S).abs())
            .sort("actor_id", "frame", "_off")
            .unique(subset=["actor_id", "frame"], keep="first", maintain_order=True)
            .drop("_off"))
    return kept, tracks.height - kept.height


def _finish(drive_id: str, parts: dict[str, Any]) -> pl.DataFrame:
    n = len(parts["actor_id"])
    data = {"drive_id": [drive_id] * n, **parts}
    out = pl.DataFrame(data).with_columns(
        pl.lit(None, pl.Float64).alias(c) for c in ("speed_mps", "accel_mps2") if c not in parts)
    return out.select(schema.TRACKS.column_names).cast(schema.TRACKS.polars_schema)


def _ridden(ann: pl.DataFrame) -> tuple[pl.Series, list[str]]:
    """Mask of annotation rows that are the other box of a rider + vehicle pair, and the reasons."""
    drop = pl.Series("drop", [False] * ann.height)
    reasons = []
    indexed = ann.with_row_index("_row")
    for dropped, partner in _RIDDEN:
        a = indexed.filter(pl.col("category") == dropped).select("_row", "timestamp_ns", "tx_m", "ty_m")
        b = ann.filter(pl.col("category") == partner).select("timestamp_ns", bx="tx_m", by="ty_m")
        if a.is_empty() or b.is_empty():
            continue
        rows = (a.join(b, on="timestamp_ns")
                .filter((pl.col("tx_m") - pl.col("bx")) ** 2 + (pl.col("ty_m") - pl.col("by")) ** 2
                        <= RIDER_MATCH_M ** 2)
                .get_column("_row").unique())
        if rows.len():
            drop = drop.scatter(rows.to_numpy(), True)
            reasons.append(f"{rows.len()} {dropped} row(s) within {RIDER_MATCH_M:g} m of a {partner} dropped "
                           f"(one road user: the {'rider' if dropped != 'MOTORCYCLIST' else 'motorcycle'} is the "
                           "actor)")
    return drop, reasons


def _unknown(categories: pl.Series, known: dict[str, str], path: Path) -> tuple[pl.Series, str | None]:
    unknown = ~categories.is_in(list(known)) | categories.is_null()
    if not unknown.any():
        return unknown, None
    counts = categories.filter(unknown).fill_null("<null>").value_counts(sort=True)
    named = ", ".join(f"{c} ({n})" for c, n in counts.iter_rows())
    return unknown, (f"{int(unknown.sum())} row(s) of unmapped AV2 categor(y/ies) dropped: {named}; "
                     f"add them to the kind table of logiq_sql/ingestion/readers/av2.py ({path.name})")


def _read_sensor_log(folder: Path) -> DriveData:
    drive_id = folder.name
    ann_path = next((folder / n for n in ANNOTATION_FILES if (folder / n).is_file()), None)
    if ann_path is None:
        raise InputError(f"{folder}: no annotations.feather (or annotations_with_ego.feather). Fix: copy the log's "
                         "annotation file from the AV2 sensor dataset into this folder.")
    pose_path = folder / POSE_FILE
    if not pose_path.is_file():
        raise InputError(
            f"{pose_path}: missing: the ego poses are needed to place the ego-frame boxes in the city frame. "
            f"Fix: copy the log's {POSE_FILE} from the AV2 sensor dataset beside {ann_path.name}."
        )
    ann = _read_table(ann_path, _ANNOTATION_COLUMNS, "AV2 annotation file")
    poses = _read_table(pose_path, _POSE_COLUMNS, "AV2 ego pose file").sort("timestamp_ns")
    poses = poses.filter(pl.all_horizontal(pl.col(c).is_not_null() & pl.col(c).is_finite()
                                           for c in _POSE_COLUMNS[1:]))
    if poses.is_empty() or ann.is_empty():
        empty = pose_path if poses.is_empty() else ann_path
        raise InputError(f"{empty}: no rows with finite values. Fix: copy the file again from the AV2 dataset.")
    map_path, archive = _map_archive(folder)
    reasons: list[str] = []
    stamped = ann.filter(pl.col("timestamp_ns").is_not_null())
    unstamped = ann.height - stamped.height
    if stamped.is_empty():
        raise InputError(f"{ann_path}: no row has a timestamp_ns. Fix: copy the file again from the AV2 dataset.")
    if unstamped:
        reasons.append(f"{unstamped} annotation row(s) without timestamp_ns dropped")
    ann = stamped

    is_ego = (ann["category"] == EGO_CATEGORY).fill_null(False)
    ego_rows = ann.filter(is_ego)
    length, width = EGO_LENGTH_M, EGO_WIDTH_M
    if ego_rows.height:
        length, width = float(ego_rows["length_m"].median()), float(ego_rows["width_m"].median())
    stamps = np.unique(ann["timestamp_ns"].drop_nulls().to_numpy())
    t0 = stamps[0]
    objects = ann.filter(~is_ego)
    rows_read = objects.height + stamps.size + unstamped

    # rows that are not actors of their own: unmapped categories, the second box of a rider + vehicle pair
    unknown, why = _unknown(objects["category"], SENSOR_KINDS, ann_path)
    if why:
        reasons.append(why)
    ridden, why_ridden = _ridden(objects)
    reasons += why_ridden
    objects = objects.filter(~unknown & ~ridden)

    pose_stamps = poses["timestamp_ns"].to_numpy()
    pose_r, pose_t = _rotations(_q(poses)), _t(poses)

    # objects: city_T_obj = city_T_ego(t) o ego_T_obj
    idx, gap = _nearest(pose_stamps, objects["timestamp_ns"].to_numpy())
    r = np.einsum("nij,njk->nik", pose_r[idx], _rotations(_q(objects)))
    xyz = np.einsum("nij,nj->ni", pose_r[idx], _t(objects)) + pose_t[idx]
    ok = (gap <= POSE_MAX_GAP_NS) & np.isfinite(xyz[:, :2]).all(axis=1)
    no_pose = int((gap > POSE_MAX_GAP_NS).sum())
    bad = int((~ok).sum()) - no_pose
    if no_pose:
        reasons.append(f"{no_pose} annotation row(s) with no ego pose within {POSE_MAX_GAP_NS / 1e6:g} ms dropped")
    if bad:
        reasons.append(f"{bad} annotation row(s) with a non-finite box pose dropped")
    t_obj = (objects["timestamp_ns"].to_numpy()[ok] - t0) / 1e9
    obj = _finish(drive_id, {
        "actor_id": objects["track_uuid"].to_numpy()[ok],
        "kind": objects["category"].replace_strict(SENSOR_KINDS, default=None).to_numpy()[ok],
        "is_ego": np.zeros(int(ok.sum()), dtype=bool),
        "frame": _frames(t_obj), "t_s": t_obj, "x_m": xyz[ok, 0], "y_m": xyz[ok, 1], "heading_rad": _yaw(r[ok]),
        "length_m": objects["length_m"].to_numpy()[ok], "width_m": objects["width_m"].to_numpy()[ok],
    })

    # the ego at every annotation timestamp, its box centre ahead of the rear axle
    idx, gap = _nearest(pose_stamps, stamps)
    keep = gap <= POSE_MAX_GAP_NS
    if (~keep).any():
        reasons.append(f"{int((~keep).sum())} ego sample(s) with no pose within {POSE_MAX_GAP_NS / 1e6:g} ms dropped")
    idx = idx[keep]
    heading = _yaw(pose_r[idx])
    t_ego = (stamps[keep] - t0) / 1e9
    n = int(keep.sum())
    ego = _finish(drive_id, {
        "actor_id": [EGO_ACTOR_ID] * n, "kind": ["vehicle"] * n, "is_ego": np.ones(n, dtype=bool),
        "frame": _frames(t_ego), "t_s": t_ego,
        "x_m": pose_t[idx, 0] + EGO_CENTRE_AHEAD_M * pose_r[idx, 0, 0],
        "y_m": pose_t[idx, 1] + EGO_CENTRE_AHEAD_M * pose_r[idx, 1, 0],
        "heading_rad": heading, "length_m": np.full(n, length), "width_m": np.full(n, width),
    })

    tracks, doubled = _one_per_frame(pl.concat([ego, obj]))
    if doubled:
        reasons.append(f"{doubled} row(s) falling in a frame their actor already has dropped (the row nearer to "
                       "frame * 0.1 s kept)")
    lanes, successors, junctions = _map(drive_id, map_path, archive)
    return DriveData(
        drive_id=drive_id, source_format="av2", source_path=str(folder), dt_s=DT_S, tracks=tracks,
        map_id=drive_id, lanes=lanes, lane_successors=successors, junctions=junctions, ego_actor_id=EGO_ACTOR_ID,
        rows_read=rows_read, rows_rejected=rows_read - tracks.height, reject_reason="; ".join(reasons) or None,
        attribution=ATTRIBUTION,
    )


def _read_scenario(folder: Path, path: Path) -> DriveData:
    df = _read_table(path, _SCENARIO_COLUMNS, "AV2 motion-forecasting scenario")
    drive_id = path.stem.removeprefix("scenario_")
    if "scenario_id" in df.columns and df["scenario_id"].n_unique() == 1 and df["scenario_id"][0]:
        drive_id = str(df["scenario_id"][0])
    map_path, archive = _map_archive(folder)
    reasons: list[str] = []
    rows_read = df.height
    df = df.with_columns(pl.col("track_id").cast(pl.String))
    is_ego = (df["track_id"] == FORECASTING_EGO).fill_null(False)
    types = pl.when(is_ego).then(pl.lit("vehicle")).otherwise(pl.col("object_type"))
    df = df.with_columns(_type=types)
    unknown, why = _unknown(df["_type"], FORECASTING_KINDS, path)
    if why:
        reasons.append(why)
    df = df.filter(~unknown)
    finite = pl.all_horizontal(pl.col(c).cast(pl.Float64).is_finite().fill_null(False)
                               for c in ("position_x", "position_y", "heading")) & pl.col("timestep").is_not_null()
    bad = df.height - df.filter(finite).height
    if bad:
        reasons.append(f"{bad} row(s) with a missing or non-finite position, heading or timestep dropped")
    df = df.filter(finite)
    ego = (df["track_id"] == FORECASTING_EGO).to_numpy()
    h = df["heading"].to_numpy().astype(float)
    vx, vy = df["velocity_x"].to_numpy().astype(float), df["velocity_y"].to_numpy().astype(float)
    frame = df["timestep"].to_numpy().astype(np.int64)
    ahead = np.where(ego, EGO_CENTRE_AHEAD_M, 0.0)
    tracks = _finish(drive_id, {
        "actor_id": df["track_id"].to_numpy(),
        "kind": df["_type"].replace_strict(FORECASTING_KINDS, default=None).to_numpy(),
        "is_ego": ego, "frame": frame, "t_s": np.round(frame * DT_S, 9),
        "x_m": df["position_x"].to_numpy() + ahead * np.cos(h), "y_m": df["position_y"].to_numpy() + ahead * np.sin(h),
        "heading_rad": h, "speed_mps": vx * np.cos(h) + vy * np.sin(h), "accel_mps2": np.full(h.size, np.nan),
        "length_m": np.where(ego, EGO_LENGTH_M, np.nan), "width_m": np.where(ego, EGO_WIDTH_M, np.nan),
    }).with_columns(pl.col(c).fill_nan(None) for c in ("speed_mps", "accel_mps2", "length_m", "width_m"))
    tracks, doubled = _one_per_frame(tracks)
    if doubled:
        reasons.append(f"{doubled} duplicated (track_id, timestep) row(s) dropped, first kept")
    lanes, successors, junctions = _map(drive_id, map_path, archive)
    return DriveData(
        drive_id=drive_id, source_format="av2", source_path=str(folder), dt_s=DT_S, tracks=tracks,
        map_id=drive_id, lanes=lanes, lane_successors=successors, junctions=junctions,
        ego_actor_id=FORECASTING_EGO if ego.any() else None, rows_read=rows_read,
        rows_rejected=rows_read - tracks.height, reject_reason="; ".join(reasons) or None, attribution=ATTRIBUTION,
    )


# ------------------------------------------------------------------------------------------------------- map

def _points(path: Path, lane_id: str, seg: dict, key: str) -> np.ndarray:
    pts = seg.get(key)
    try:
        xy = np.array([(float(p["x"]), float(p["y"])) for p in pts], dtype=float).reshape(-1, 2)
    except (TypeError, KeyError, ValueError):
        xy = np.empty((0, 2))
    if len(xy) < 2 or not np.isfinite(xy).all():
        raise InputError(f"{path}: lane segment {lane_id}: '{key}' is not a list of at least 2 points with numeric "
                         "x and y. Fix: repair the map archive or copy it again from the AV2 dataset.")
    return xy


def _resample(line: np.ndarray, n: int) -> np.ndarray:
    """``n`` points spaced evenly by arc length along the polyline (ends kept)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
    if s[-1] <= 0:
        return np.repeat(line[:1], n, axis=0)
    u = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(u, s, line[:, 0]), np.interp(u, s, line[:, 1])])


def _largest_polygon(geom: shapely.Geometry) -> shapely.Polygon | None:
    geom = shapely.set_precision(geom, WKT_GRID_M)
    parts = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and not g.is_empty]
    return max(parts, key=lambda g: g.area) if parts else None


def _lane_geometry(left: np.ndarray, right: np.ndarray) -> tuple[shapely.Polygon, shapely.LineString]:
    ring = np.vstack([left, right[::-1]])
    poly = shapely.Polygon(ring)
    poly = _largest_polygon(poly if poly.is_valid else shapely.make_valid(poly))
    if poly is None:  # zero-area segment (both boundaries on one line): a thin sliver keeps it findable
        poly = _largest_polygon(shapely.LineString(ring).buffer(0.01))
    n = max(len(left), len(right))
    mid = (_resample(left, n) + _resample(right, n)) / 2
    mid = mid[np.r_[True, np.any(np.abs(np.diff(mid, axis=0)) > WKT_GRID_M / 2, axis=1)]]
    if len(mid) < 2:  # both boundaries collapse to a point: a centre line of zero length is still a line
        mid = np.vstack([mid[:1], mid[:1]])
    return poly, shapely.LineString(mid)


def _direction(lines: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Direction (radians) of each line at distance s along it, from the points 0.5 m before and after."""
    before = shapely.line_interpolate_point(lines, np.maximum(s - DIRECTION_STEP_M, 0.0))
    after = shapely.line_interpolate_point(lines, np.minimum(s + DIRECTION_STEP_M, shapely.length(lines)))
    return np.arctan2(shapely.get_y(after) - shapely.get_y(before), shapely.get_x(after) - shapely.get_x(before))


def _same_direction(lines: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For lane pairs (a, b): b's direction near a's midpoint is within 90 degrees of a's."""
    if a.size == 0:
        return np.zeros(0, dtype=bool)
    mid_s = shapely.length(lines[a]) / 2
    mid = shapely.line_interpolate_point(lines[a], mid_s)
    da = _direction(lines[a], mid_s)
    db = _direction(lines[b], shapely.line_locate_point(lines[b], mid))
    return np.abs(np.arctan2(np.sin(da - db), np.cos(da - db))) < math.pi / 2


def _id_key(lane_id: str) -> tuple[int, int, str]:
    return (0, int(lane_id), "") if lane_id.isdigit() else (1, 0, lane_id)


def _map(map_id: str, path: Path, archive: dict) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """lanes, lane_successors, junctions of one AV2 map archive."""
    segments = archive["lane_segments"]
    ids = [str(k) for k in segments]
    index = {lane_id: i for i, lane_id in enumerate(ids)}
    polygons, lines, inter = [], [], []
    for lane_id, seg in zip(ids, segments.values(), strict=True):
        if not isinstance(seg, dict):
            raise InputError(f"{path}: lane segment {lane_id} is a {type(seg).__name__}, not an object.")
        poly, line = _lane_geometry(_points(path, lane_id, seg, "left_lane_boundary"),
                                    _points(path, lane_id, seg, "right_lane_boundary"))
        polygons.append(poly)
        lines.append(line)
        inter.append(bool(seg.get("is_intersection")))
    polygons_a, lines_a = np.array(polygons, dtype=object), np.array(lines, dtype=object)

    def neighbour(seg: dict, key: str) -> int:
        v = seg.get(key)
        return index.get(str(v), -1) if v is not None else -1

    neighbours = {}
    for side in ("left", "right"):
        nb = np.array([neighbour(seg, f"{side}_neighbor_id") for seg in segments.values()], dtype=np.int64)
        a = np.flatnonzero((nb >= 0) & (nb != np.arange(len(ids))))
        same = np.full(len(ids), None, dtype=object)
        same[a] = _same_direction(lines_a, a, nb[a])
        neighbours[side] = (nb, same)

    pairs: set[tuple[str, str]] = set()
    for lane_id, seg in zip(ids, segments.values(), strict=True):
        pairs |= {(lane_id, str(s)) for s in seg.get("successors") or [] if str(s) in index}
        pairs |= {(str(p), lane_id) for p in seg.get("predecessors") or [] if str(p) in index}
    pairs = sorted((p for p in pairs if p[0] != p[1]), key=lambda p: (_id_key(p[0]), _id_key(p[1])))

    junction_of, junction_rows = _junctions(ids, polygons_a, np.array(inter, dtype=bool), map_id)
    lane_rows = [
        (map_id, lane_id, None if seg.get("lane_type") is None else str(seg["lane_type"]),
         shapely.to_wkt(polygons[i], rounding_precision=WKT_DIGITS),
         shapely.to_wkt(lines[i], rounding_precision=WKT_DIGITS),
         *(v for side in ("left", "right") for v in (
             ids[neighbours[side][0][i]] if neighbours[side][0][i] >= 0 and neighbours[side][0][i] != i else None,
             neighbours[side][1][i])),
         None, junction_of.get(lane_id))
        for i, (lane_id, seg) in enumerate(zip(ids, segments.values(), strict=True))
    ]
    return (
        pl.DataFrame(lane_rows, schema=schema.LANES.polars_schema, orient="row"),
        pl.DataFrame([(map_id, a, b, None) for a, b in pairs], schema=schema.LANE_SUCCESSORS.polars_schema,
                     orient="row"),
        pl.DataFrame(junction_rows, schema=schema.JUNCTIONS.polars_schema, orient="row"),
    )


def _junctions(ids: list[str], polygons: np.ndarray, inter: np.ndarray, map_id: str
               ) -> tuple[dict[str, str], list[tuple[str, str, str]]]:
    """lane id -> junction id for intersection lanes, and the junction rows."""
    members = np.flatnonzero(inter)
    if members.size == 0:
        return {}, []
    grown = shapely.buffer(polygons[members], JUNCTION_JOIN_M, join_style="mitre")
    parts = shapely.get_parts(shapely.union_all(grown))
    part_of = np.full(members.size, -1)
    lane, part = shapely.STRtree(parts).query(shapely.point_on_surface(polygons[members]), predicate="within")
    part_of[lane] = part
    junction_of: dict[str, str] = {}
    rows = []
    for p, geom in enumerate(parts):
        lanes = [ids[members[i]] for i in np.flatnonzero(part_of == p)]
        if not lanes:
            continue
        jid = "j" + min(lanes, key=_id_key)
        junction_of.update({lane_id: jid for lane_id in lanes})
        geom = _largest_polygon(geom) or geom
        rows.append((map_id, jid, shapely.to_wkt(geom, rounding_precision=WKT_DIGITS)))
    return junction_of, sorted(rows, key=lambda r: _id_key(r[1][1:]))
