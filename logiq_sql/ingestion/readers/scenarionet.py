"""ScenarioNet scenario pickles (e.g. nuScenes-mini converted by ScenarioNet): one ``.pkl`` is one drive.

Safety
    A pickle can run any code while it loads. Files are therefore read with a restricted unpickler that builds
    only numpy arrays (``numpy.core.multiarray._reconstruct`` / ``numpy._core.multiarray._reconstruct``,
    ``numpy.ndarray``, ``numpy.dtype``, numpy scalars) and plain containers (``builtins.set``, ``frozenset``,
    ``slice``, ``complex``, ``collections.OrderedDict``). Any other global (``os.system``, ``builtins.eval``,
    ``builtins.getattr``, a class of some package, ...) is refused with an ``InputError`` before it is called.
    numpy 2 renamed ``numpy.core`` to ``numpy._core``: the old name is resolved to the new module.

Drive
    drive_id = ``metadata['id']`` (e.g. ``scene-0061``); map_id = drive_id (each scenario carries its own map
    excerpt); dt_s = ``metadata['sample_rate']``; ego_actor_id = ``metadata['sdc_id']``.

Tracks
    One row per track and per frame where ``state['valid']`` is true: frame = the array index, t_s = frame * dt_s,
    x_m / y_m = ``position[:, 0:2]``, heading_rad = ``heading``, speed_mps = the velocity projected on the heading
    (vx cos h + vy sin h), accel_mps2 = NULL (derived by the staging query). Rows with a non-finite position or
    heading are dropped and counted in ``rows_rejected``; ``rows_read`` counts every valid row.

    * Speed at the end of a valid run: ScenarioNet's nuScenes converter computes velocity as the forward difference
      of positions and writes (0, 0) on the last valid frame of every run. Such an exact (0, 0) on the last frame of
      a run of two or more frames is not a measurement: speed_mps is left NULL there and the staging query derives
      it from the positions.
    * Size: length_m / width_m from ``state['length']`` / ``state['width']``. ScenarioNet's nuScenes converter
      writes the ego (a Renault Zoe) with length 1.73 and width 4.08, i.e. swapped. Rule: for the ego and for
      actors of kind ``vehicle`` (cars), if width > length the two are swapped. Other kinds keep the annotated box
      (nuScenes annotates a 1.79 m x 2.17 m trailer in scene-0655, people and cones are often wider than long).
    * Kind, from the nuScenes category in ``track['metadata']['type']`` (checked in this order):
      ``human.pedestrian.*`` -> person, ``animal`` -> animal, ``vehicle.bicycle`` -> cyclist,
      ``vehicle.motorcycle`` -> motorcycle, ``vehicle.emergency.*`` -> emergency_vehicle, ``vehicle.bus.*`` -> bus,
      ``vehicle.trailer`` -> trailer, ``vehicle.truck`` and ``vehicle.construction`` -> truck,
      ``vehicle.car`` -> vehicle, ``movable_object.*`` (traffic cone, barrier, debris, ...) and
      ``static_object.*`` -> object. Anything else falls back on the coarse ``track['type']``:
      VEHICLE -> vehicle, CYCLIST -> cyclist, PEDESTRIAN -> person, otherwise object.
      nuScenes ``vehicle.bicycle`` also covers parked bicycles without a rider (ScenarioNet drops the
      with/without-rider attribute). A bicycle whose centre never moves more than 1 m from where it was first seen
      is a parked bicycle, not a cyclist: kind object.

Lanes
    Map features whose type starts with ``LANE`` (``LANE_SURFACE_STREET``, ...) become lanes; road lines, road
    edges, crosswalks are not lanes. lane_type = the feature type. polygon = the feature's ``polygon`` made valid
    (the largest part if that splits it); a feature without a polygon (nuScenes lane connectors, which ScenarioNet
    stores as a bare polyline) gets its centre line buffered by 1.75 m with flat ends. centerline = ``polyline``
    (x, y only, consecutive duplicate points dropped). speed_limit_mps = ``speed_limit_kmh`` / 3.6 or
    ``speed_limit_mph`` * 0.44704, except for nuScenes, whose converter writes a constant placeholder of 100 km/h on
    every lane connector: NULL there. No junctions, traffic lights or light states (nuScenes has none here).

Lane graph (vectorised with shapely 2 STRtree queries)
    Directions of a centre line are taken, as in ``logiq_sql.ingestion.localise``, from the points 0.5 m before and after.

    * Successors: when some lane lists ``exit_lanes`` / ``entry_lanes``, those lists are the graph (an entry of B
      naming A gives A -> B). Otherwise B succeeds A if B's centre line starts within 1.0 m of the end of A's and
      their directions there differ by less than 45 degrees. turn is NULL.
    * Neighbours: when some lane lists ``left_neighbor`` / ``right_neighbor``, those lists are used (the one whose
      centre line is nearest to A's midpoint; same direction if the directions differ by less than 90 degrees).
      Otherwise: from the midpoint of A's centre line, step 3.5 m perpendicular to its direction to the left (and
      to the right). A lane B != A whose polygon contains that point and whose direction at the point of its centre
      line nearest to it is within 30 degrees of A's is a same-direction neighbour; within 30 degrees of the
      opposite direction, an opposite-direction neighbour (``*_same_direction = False``). Of several candidates the
      one whose centre line is nearest to the offset point wins.
"""

from __future__ import annotations

import collections
import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import numpy._core.multiarray as _np_multiarray
import polars as pl
import shapely

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.base import DriveData

NUSCENES_ATTRIBUTION = "nuScenes (Motional), CC BY-NC-SA 4.0, via ScenarioNet; non-commercial; see SOURCE.md"

LANE_HALF_WIDTH_M = 1.75  # buffer of a lane that has a centre line but no polygon
SUCCESSOR_GAP_M = 1.0  # end of A to start of B
SUCCESSOR_MAX_TURN_RAD = math.radians(45.0)
NEIGHBOUR_OFFSET_M = 3.5  # from A's midpoint, perpendicular
NEIGHBOUR_MAX_ANGLE_RAD = math.radians(30.0)
DIRECTION_STEP_M = 0.5  # direction of a centre line from the points this far before and after
WKT_GRID_M = 1e-6  # WKT is written with 6 decimals

# The only globals a ScenarioNet pickle may name: numpy array builders and plain containers.
_ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {
    ("numpy.core.multiarray", "_reconstruct"): _np_multiarray._reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _np_multiarray._reconstruct,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("numpy.core.multiarray", "scalar"): _np_multiarray.scalar,
    ("numpy._core.multiarray", "scalar"): _np_multiarray.scalar,
    ("builtins", "set"): set,
    ("builtins", "frozenset"): frozenset,
    ("builtins", "slice"): slice,
    ("builtins", "complex"): complex,
    ("collections", "OrderedDict"): collections.OrderedDict,
}
_PY2_MODULES = {"__builtin__": "builtins"}  # protocol 0-2 pickles name the builtins module the Python 2 way


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that resolves only ``_ALLOWED_GLOBALS`` and refuses everything else."""

    def __init__(self, file: Any, path: Path) -> None:
        super().__init__(file)
        self._path = path

    def find_class(self, module: str, name: str) -> Any:
        key = (_PY2_MODULES.get(module, module), name)
        if key in _ALLOWED_GLOBALS:
            return _ALLOWED_GLOBALS[key]
        raise InputError(
            f"{self._path}: refused to load: the pickle asks for '{module}.{name}', which is not a numpy array or a "
            "plain builtin. Fix: only load ScenarioNet files you trust, converted with numpy arrays and plain "
            "containers."
        )

    def persistent_load(self, pid: Any) -> Any:
        raise InputError(
            f"{self._path}: refused to load: the pickle asks for a persistent object, which is not a numpy array or "
            "a plain builtin. Fix: only load ScenarioNet files you trust, converted with numpy arrays and plain "
            "containers."
        )


def safe_load(path: Path) -> Any:
    """Unpickle ``path`` with the restricted unpickler; InputError if refused, truncated or corrupt."""
    try:
        with open(path, "rb") as f:
            return _RestrictedUnpickler(f, path).load()
    except InputError:
        raise
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc}).") from None
    except Exception as exc:  # EOFError, UnpicklingError, ValueError, TypeError, ... from a damaged stream
        raise InputError(
            f"{path}: the file is truncated or not a pickle ({type(exc).__name__}: {exc}). "
            "Fix: copy the ScenarioNet .pkl again from its source."
        ) from None


def _require(path: Path, mapping: Any, key: str, where: str) -> Any:
    if not isinstance(mapping, dict):
        raise InputError(f"{path}: {where} is a {type(mapping).__name__}, not a dict; not a ScenarioNet scenario.")
    if key not in mapping:
        raise InputError(
            f"{path}: missing key '{key}' in {where}. Fix: give a ScenarioNet scenario description "
            "(keys metadata, tracks, map_features; metadata id, sdc_id, sample_rate)."
        )
    return mapping[key]


def _kind(coarse: Any, fine: Any) -> str:
    fine = str(fine or "").lower()
    if fine.startswith("human.pedestrian"):
        return "person"
    if fine.startswith("animal"):
        return "animal"
    if fine.startswith("vehicle."):
        for prefix, kind in (
            ("vehicle.bicycle", "cyclist"), ("vehicle.motorcycle", "motorcycle"),
            ("vehicle.emergency", "emergency_vehicle"), ("vehicle.bus", "bus"), ("vehicle.trailer", "trailer"),
            ("vehicle.truck", "truck"), ("vehicle.construction", "truck"), ("vehicle.car", "vehicle"),
        ):
            if fine.startswith(prefix):
                return kind
    if fine.startswith(("movable_object", "static_object")):
        return "object"
    return {"VEHICLE": "vehicle", "CYCLIST": "cyclist", "PEDESTRIAN": "person"}.get(str(coarse).upper(), "object")


def _column(path: Path, tid: str, state: dict, key: str, n: int, width: int | None = None) -> np.ndarray:
    arr = np.asarray(_require(path, state, key, f"tracks['{tid}']['state']"), dtype=float)
    if width is None:
        if arr.size != n:
            raise InputError(f"{path}: tracks['{tid}']['state']['{key}'] has {arr.size} values, expected {n}.")
        return arr.reshape(n)
    if arr.ndim != 2 or arr.shape[0] != n or arr.shape[1] < width:
        raise InputError(
            f"{path}: tracks['{tid}']['state']['{key}'] has shape {arr.shape}, expected ({n}, {width} or more).")
    return arr[:, :width]


def _tracks(path: Path, drive_id: str, tracks: Any, sdc_id: str, dt: float) -> tuple[pl.DataFrame, int, int]:
    """Track rows (schema.TRACKS), rows read, rows rejected."""
    if not isinstance(tracks, dict):
        raise InputError(f"{path}: 'tracks' is a {type(tracks).__name__}, not a dict of tracks.")
    parts: list[dict[str, Any]] = []
    rows_read = rejected = 0
    for raw_id, track in tracks.items():
        tid = str(raw_id)
        state = _require(path, track, "state", f"tracks['{tid}']")
        valid = np.asarray(_require(path, state, "valid", f"tracks['{tid}']['state']")).reshape(-1)
        valid = valid.astype(float) > 0.5 if valid.dtype != bool else valid
        n = valid.size
        if not valid.any():
            continue
        pos = _column(path, tid, state, "position", n, 2)
        heading = _column(path, tid, state, "heading", n)
        vel = _column(path, tid, state, "velocity", n, 2) if "velocity" in state else np.full((n, 2), np.nan)
        length = _column(path, tid, state, "length", n) if "length" in state else np.full(n, np.nan)
        width = _column(path, tid, state, "width", n) if "width" in state else np.full(n, np.nan)
        meta = track.get("metadata") or {}
        kind = _kind(track.get("type"), meta.get("type") if isinstance(meta, dict) else None)
        is_ego = tid == sdc_id
        if kind == "cyclist":  # a bicycle that never moves is parked: an object, not a cyclist
            seen = pos[valid & np.isfinite(pos).all(axis=1)]
            if len(seen) and np.hypot(*(seen - seen[0]).T).max() <= 1.0:
                kind = "object"
        if is_ego or kind == "vehicle":  # the nuScenes ego comes with length and width swapped
            swap = width > length
            length, width = np.where(swap, width, length), np.where(swap, length, width)
        speed = vel[:, 0] * np.cos(heading) + vel[:, 1] * np.sin(heading)
        # last frame of each valid run: the converter writes velocity (0, 0) there, which is not a measurement
        run_end = valid & ~np.r_[valid[1:], False]
        run_long = valid & np.r_[False, valid[:-1]]
        speed[run_end & run_long & (vel[:, 0] == 0) & (vel[:, 1] == 0)] = np.nan
        frames = np.flatnonzero(valid)
        rows_read += frames.size
        ok = np.isfinite(pos[frames]).all(axis=1) & np.isfinite(heading[frames])
        rejected += int((~ok).sum())
        frames = frames[ok]
        if frames.size == 0:
            continue
        parts.append({
            "actor_id": tid, "kind": kind, "is_ego": is_ego, "frame": frames,
            "x_m": pos[frames, 0], "y_m": pos[frames, 1], "heading_rad": heading[frames],
            "speed_mps": speed[frames], "length_m": length[frames], "width_m": width[frames],
        })
    if not parts:
        return schema.empty(schema.TRACKS), rows_read, rejected
    frame = np.concatenate([p["frame"] for p in parts]).astype(np.int64)
    sizes = [p["frame"].size for p in parts]
    data = {
        "drive_id": [drive_id] * frame.size,
        "actor_id": np.repeat([p["actor_id"] for p in parts], sizes),
        "kind": np.repeat([p["kind"] for p in parts], sizes),
        "is_ego": np.repeat([p["is_ego"] for p in parts], sizes),
        "frame": frame,
        "t_s": np.round(frame * dt, 9),
        **{c: np.concatenate([p[c] for p in parts]) for c in ("x_m", "y_m", "heading_rad", "speed_mps")},
        "accel_mps2": np.full(frame.size, np.nan),
        **{c: np.concatenate([p[c] for p in parts]) for c in ("length_m", "width_m")},
    }
    out = pl.DataFrame(data, schema=schema.TRACKS.polars_schema)
    # NaN means unknown in the optional columns: NULL, so the staging query derives or defaults it
    out = out.with_columns(pl.col(c).fill_nan(None) for c in ("heading_rad", "speed_mps", "accel_mps2",
                                                              "length_m", "width_m"))
    return out, rows_read, rejected


def _centerline(polyline: Any) -> shapely.LineString | None:
    try:
        xy = np.asarray(polyline, dtype=float)
    except (TypeError, ValueError):
        return None
    if xy.ndim != 2 or xy.shape[1] < 2:
        return None
    xy = xy[:, :2]
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) == 0:
        return None
    xy = xy[np.r_[True, np.any(np.diff(xy, axis=0) != 0, axis=1)]]
    if len(xy) < 2:
        return None
    line = shapely.set_precision(shapely.LineString(xy), WKT_GRID_M)  # also drops points equal on that grid
    return line if line.geom_type == "LineString" and not line.is_empty and line.length > 0 else None


def _polygon(polygon: Any, centerline: shapely.LineString) -> shapely.Polygon | None:
    """The feature's polygon made valid (largest part), else the centre line buffered with flat ends.

    Snapped to the 1e-6 m grid the WKT is written on, so that the written polygon is valid too.
    """
    geom = None
    if polygon is not None:
        try:
            xy = np.asarray(polygon, dtype=float)
            if xy.ndim == 2 and xy.shape[1] >= 2 and len(xy) >= 3 and np.isfinite(xy[:, :2]).all():
                geom = _largest_polygon(shapely.make_valid(shapely.Polygon(xy[:, :2])))
        except (TypeError, ValueError, shapely.errors.GEOSException):
            geom = None
    if geom is None:
        geom = _largest_polygon(shapely.buffer(centerline, LANE_HALF_WIDTH_M, cap_style="flat"))
    return geom


def _largest_polygon(geom: shapely.Geometry) -> shapely.Polygon | None:
    geom = shapely.set_precision(geom, WKT_GRID_M)
    parts = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and not g.is_empty]
    return max(parts, key=lambda g: g.area) if parts else None


def _direction(lines: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Direction (radians) of each line at distance s along it, from the points 0.5 m before and after."""
    before = shapely.line_interpolate_point(lines, np.maximum(s - DIRECTION_STEP_M, 0.0))
    after = shapely.line_interpolate_point(lines, np.minimum(s + DIRECTION_STEP_M, shapely.length(lines)))
    return np.arctan2(shapely.get_y(after) - shapely.get_y(before), shapely.get_x(after) - shapely.get_x(before))


def _angle_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| wrapped into [0, pi]."""
    return np.abs(np.arctan2(np.sin(a - b), np.cos(a - b)))


def _nearest_per_lane(a: np.ndarray, b: np.ndarray, dist: np.ndarray, n: int) -> np.ndarray:
    """For each lane index 0..n-1 the b with the smallest dist among its pairs, else -1."""
    best = np.full(n, -1, dtype=np.int64)
    if a.size:
        order = np.lexsort((dist, a))
        first = np.r_[True, a[order][1:] != a[order][:-1]]
        best[a[order][first]] = b[order][first]
    return best


def _ids(entries: Any) -> list[str]:
    """Lane ids from an exit/entry/neighbour list: plain ids or dicts with 'feature_id' / 'id'."""
    if entries is None:
        return []
    if isinstance(entries, (str, int, np.integer)):
        entries = [entries]
    out = []
    for e in entries:
        if isinstance(e, dict):
            e = e.get("feature_id", e.get("id"))
        if e is not None:
            out.append(str(e))
    return out


def _successors(ids: list[str], features: list[dict], lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(from, to) lane index pairs."""
    index = {lane_id: i for i, lane_id in enumerate(ids)}
    if any(_ids(f.get("exit_lanes")) or _ids(f.get("entry_lanes")) for f in features):
        pairs = set()
        for i, f in enumerate(features):
            pairs |= {(i, index[j]) for j in _ids(f.get("exit_lanes")) if j in index}
            pairs |= {(index[j], i) for j in _ids(f.get("entry_lanes")) if j in index}
        pairs = sorted(p for p in pairs if p[0] != p[1])
        return np.array([p[0] for p in pairs], dtype=np.int64), np.array([p[1] for p in pairs], dtype=np.int64)
    lengths = shapely.length(lines)
    starts = shapely.line_interpolate_point(lines, 0.0)
    ends = shapely.line_interpolate_point(lines, lengths)
    a, b = shapely.STRtree(starts).query(ends, predicate="dwithin", distance=SUCCESSOR_GAP_M)
    keep = a != b
    a, b = a[keep], b[keep]
    turn = _angle_diff(_direction(lines[a], lengths[a]), _direction(lines[b], np.zeros(b.size)))
    keep = turn < SUCCESSOR_MAX_TURN_RAD
    order = np.lexsort((b[keep], a[keep]))
    return a[keep][order], b[keep][order]


def _neighbours(ids: list[str], features: list[dict], lines: np.ndarray, polygons: np.ndarray
                ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """side -> (neighbour index or -1, same direction) per lane."""
    n = len(ids)
    index = {lane_id: i for i, lane_id in enumerate(ids)}
    mid_s = shapely.length(lines) / 2.0
    mid = shapely.line_interpolate_point(lines, mid_s)
    heading = _direction(lines, mid_s)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    from_keys = any(_ids(f.get("left_neighbor")) or _ids(f.get("right_neighbor")) for f in features)
    tree = shapely.STRtree(polygons)
    for side, sign in (("left", 1.0), ("right", -1.0)):
        if from_keys:
            pairs = [(i, index[j]) for i, f in enumerate(features) for j in _ids(f.get(f"{side}_neighbor"))
                     if j in index and index[j] != i]
            a = np.array([p[0] for p in pairs], dtype=np.int64)
            b = np.array([p[1] for p in pairs], dtype=np.int64)
            probe = mid[a]
        else:
            offset = shapely.points(
                shapely.get_x(mid) - sign * NEIGHBOUR_OFFSET_M * np.sin(heading),
                shapely.get_y(mid) + sign * NEIGHBOUR_OFFSET_M * np.cos(heading),
            )
            a, b = tree.query(offset, predicate="intersects")
            keep = a != b
            a, b = a[keep], b[keep]
            probe = offset[a]
        s = shapely.line_locate_point(lines[b], probe)
        diff = _angle_diff(_direction(lines[b], s), heading[a])
        if from_keys:
            same = diff < math.pi / 2
        else:
            same = diff < NEIGHBOUR_MAX_ANGLE_RAD
            keep = same | (diff > math.pi - NEIGHBOUR_MAX_ANGLE_RAD)
            a, b, probe, same = a[keep], b[keep], probe[keep], same[keep]
        best = _nearest_per_lane(a, b, shapely.distance(lines[b], probe), n)
        same_of = np.zeros(n, dtype=bool)
        if a.size:
            chosen = best[a] == b
            same_of[a[chosen]] = same[chosen]
        out[side] = (best, same_of)
    return out


def _speed_limit(feature: dict, dataset: str) -> float | None:
    if dataset == "nuscenes":  # the converter's constant 100 km/h on lane connectors is a placeholder
        return None
    for key, factor in (("speed_limit_kmh", 1 / 3.6), ("speed_limit_mph", 0.44704), ("speed_limit_mps", 1.0)):
        value = feature.get(key)
        if isinstance(value, (int, float, np.number)) and math.isfinite(value) and value > 0:
            return float(value) * factor
    return None


def _lanes(map_id: str, map_features: Any, dataset: str) -> tuple[pl.DataFrame, pl.DataFrame]:
    if not isinstance(map_features, dict):
        return schema.empty(schema.LANES), schema.empty(schema.LANE_SUCCESSORS)
    ids: list[str] = []
    features: list[dict] = []
    centerlines: list[shapely.LineString] = []
    polygons: list[shapely.Polygon] = []
    for fid, feature in map_features.items():
        if not isinstance(feature, dict) or not str(feature.get("type", "")).upper().startswith("LANE"):
            continue
        line = _centerline(feature.get("polyline"))
        area = None if line is None else _polygon(feature.get("polygon"), line)
        if area is None:  # no usable centre line: not a lane we can place
            continue
        ids.append(str(fid))
        features.append(feature)
        centerlines.append(line)
        polygons.append(area)
    if not ids:
        return schema.empty(schema.LANES), schema.empty(schema.LANE_SUCCESSORS)
    lines = np.array(centerlines, dtype=object)
    polys = np.array(polygons, dtype=object)
    id_arr = np.array(ids, dtype=object)
    nb = _neighbours(ids, features, lines, polys)
    left, left_same = nb["left"]
    right, right_same = nb["right"]
    lanes = pl.DataFrame({
        "map_id": [map_id] * len(ids),
        "lane_id": ids,
        "lane_type": [str(f.get("type")) for f in features],
        "polygon_wkt": shapely.to_wkt(polys, rounding_precision=6).tolist(),
        "centerline_wkt": shapely.to_wkt(lines, rounding_precision=6).tolist(),
        "left_lane_id": [ids[j] if j >= 0 else None for j in left],
        "left_same_direction": [bool(s) if j >= 0 else None for j, s in zip(left, left_same, strict=False)],
        "right_lane_id": [ids[j] if j >= 0 else None for j in right],
        "right_same_direction": [bool(s) if j >= 0 else None for j, s in zip(right, right_same, strict=False)],
        "speed_limit_mps": [_speed_limit(f, dataset) for f in features],
        "junction_id": [None] * len(ids),
    }, schema=schema.LANES.polars_schema)
    a, b = _successors(ids, features, lines)
    successors = pl.DataFrame({
        "map_id": [map_id] * a.size, "lane_id": id_arr[a].tolist(), "successor_id": id_arr[b].tolist(),
        "turn": [None] * a.size,
    }, schema=schema.LANE_SUCCESSORS.polars_schema)
    return lanes, successors


def read_scenarionet(path: str | Path) -> list[DriveData]:
    """Read one ScenarioNet scenario pickle into one DriveData (see the module docstring for the rules)."""
    path = Path(path)
    scenario = safe_load(path)
    if not isinstance(scenario, dict):
        raise InputError(
            f"{path}: the pickle holds a {type(scenario).__name__}, not a ScenarioNet scenario description (a dict).")
    meta = _require(path, scenario, "metadata", "the scenario")
    tracks = _require(path, scenario, "tracks", "the scenario")
    map_features = _require(path, scenario, "map_features", "the scenario")
    drive_id = str(_require(path, meta, "id", "metadata"))
    sdc_id = str(_require(path, meta, "sdc_id", "metadata"))
    dt = _require(path, meta, "sample_rate", "metadata")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        dt = float("nan")
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"{path}: metadata['sample_rate'] is {meta['sample_rate']!r}, not a positive number of "
                         "seconds.")
    dataset = str(meta.get("dataset") or "unknown dataset")
    attribution = (NUSCENES_ATTRIBUTION if dataset == "nuscenes"
                   else f"{dataset}, via ScenarioNet; see the dataset's own licence")
    rows, rows_read, rejected = _tracks(path, drive_id, tracks, sdc_id, dt)
    lanes, successors = _lanes(drive_id, map_features, dataset)
    return [DriveData(
        drive_id=drive_id,
        source_format="scenarionet",
        source_path=str(path),
        dt_s=dt,
        tracks=rows,
        map_id=drive_id,
        lanes=lanes,
        lane_successors=successors,
        ego_actor_id=sdc_id,
        rows_read=rows_read,
        rows_rejected=rejected,
        reject_reason=f"{rejected} row(s) with a non-finite position or heading" if rejected else None,
        attribution=attribution,
    )]
