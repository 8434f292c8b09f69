"""CommonRoad XML scenarios (versions 2018b and 2020a, plain ``.xml`` or gzipped ``.xml.gz``).

One file is one drive: ``drive_id = map_id = f"{benchmarkID}@{commonRoadVersion}"`` (the version is part of the
id because some 2020a files reuse the benchmarkID of a 2018b file with other traffic and map).

Tracks
    One row per dynamic obstacle per state: the ``initialState`` and every ``trajectory/state``. ``frame`` is the
    state's integer time step, ``t_s = frame * timeStepSize``. Positions are the box centre (CommonRoad's
    convention). Values given as an interval (``intervalStart``/``intervalEnd``) instead of ``exact`` are read
    as the interval's midpoint. ``length_m``/``width_m`` come from the ``rectangle`` shape (a ``circle`` gives
    its diameter for both; other shapes leave them NULL). The obstacle type maps to a kind with ``_KINDS``
    (unknown types become ``object``). There is no recorded ego: ``is_ego`` is False, ``ego_actor_id`` None.

    Only *dynamic* obstacles are read (2018b ``<obstacle>`` with ``role`` dynamic, 2020a ``<dynamicObstacle>``).
    Static obstacles (2018b role static, 2020a ``<staticObstacle>``, environment/phantom obstacles) are
    ignored: the NGSIM scenarios have none. An ``<occupancySet>`` (the predicted occupancy polygons of the
    set-based "S" scenarios) is not a recorded state and is ignored, so such an obstacle keeps only its
    initial state.

    A state whose x, y, orientation or velocity is missing or non-finite is dropped; ``rows_read`` counts every
    state seen, ``rows_rejected`` the dropped ones and ``reject_reason`` names their obstacle ids. A missing
    acceleration is NULL.

Map (``map_id`` = ``drive_id``)
    lanes: one row per lanelet. Polygon = leftBound points followed by the reversed rightBound points (repaired
    with ``shapely.make_valid`` only when invalid, keeping the largest polygon part). Centre line = pointwise
    midpoints of the two bounds, after resampling both to the same number of points by arc length when their
    point counts differ. WKT is written with 4 decimals. Neighbours from ``adjacentLeft``/``adjacentRight``
    (``*_same_direction`` = ``drivingDir == "same"``). ``lane_type`` = first ``laneletType`` (2020a) else
    NULL. ``speed_limit_mps`` = the lanelet's ``speedLimit`` (2018b, m/s); in 2020a files, where speed limits
    are traffic signs, the lowest ``additionalValue`` (m/s) of a referenced speed-limit sign (``R2-1``,
    ``274``, ``MAX_SPEED``); else NULL. ``junction_id`` = id of the ``<intersection>`` that lists the lanelet
    as ``successorsLeft/Straight/Right`` of one of its incomings, else NULL.

    lane_successors: one row per ``<successor ref>``. ``turn`` is left/straight/right when the successor is
    listed as ``successorsLeft/Straight/Right`` of an incoming whose ``incomingLanelet`` is the predecessor,
    else NULL.

    junctions: one row per intersection, polygon = union of its junction lanelets' polygons (an intersection
    with no such lanelet gives no row).

    traffic_lights: one row per (light, lanelet whose ``trafficLightRef`` -- directly under the lanelet or in
    its ``stopLine`` -- names the light); x/y from the light's ``position/point`` when present; direction from
    its ``<direction>`` (leftStraight -> "left,straight", all or absent -> NULL = every movement). A light that no
    lanelet references has no row here (``lane_id`` is required) but still gets its states.

Traffic light states
    For every light with a ``<cycle>``: one row per frame 0..max_frame of the drive (max_frame = the largest
    state time step of the drive's obstacles). The cycle elements (duration in time steps, colour) repeat with
    period ``L`` = the sum of the durations, and the cycle *starts* at time step ``timeOffset``: at frame ``k``
    the position in the cycle is ``p = (k - timeOffset) mod L`` (non-negative modulo) and the state is the
    colour of the element whose cumulative-duration span contains ``p``. This is the convention of
    commonroad-io's ``TrafficLight.get_state_at_time_step``. Colours: green, yellow, red, redYellow ->
    red_yellow, inactive -> off, anything else -> unknown. A light with ``<active>false</active>`` is ``off``
    at every frame.
"""

from __future__ import annotations

import gc
import gzip
import math
import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np
import polars as pl
import shapely
from shapely.geometry import LineString, Polygon

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.base import DriveData

ATTRIBUTION = "NGSIM (FHWA/US DOT public data) via CommonRoad (TUM); see SOURCE.md"

_KINDS = {
    "car": "vehicle", "truck": "truck", "bus": "bus", "bicycle": "cyclist", "pedestrian": "person",
    "motorcycle": "motorcycle", "priorityVehicle": "emergency_vehicle", "parkedVehicle": "stationary_vehicle",
    "taxi": "vehicle",
}
_COLOURS = {"green": "green", "yellow": "yellow", "red": "red", "redYellow": "red_yellow", "inactive": "off"}
# CommonRoad TrafficLightDirection -> the movements it governs (``all`` and unknown values: every movement)
_DIRECTIONS = {"right": "right", "straight": "straight", "left": "left", "leftStraight": "left,straight",
               "straightRight": "straight,right", "leftRight": "left,right", "all": None}
_TURNS = (("successorsLeft", "left"), ("successorsStraight", "straight"), ("successorsRight", "right"))
_SPEED_SIGNS = {"R2-1", "274", "MAX_SPEED"}
_WKT_DIGITS = 4
_NAN = float("nan")
_INDENT = re.compile(rb">\s+<")


# ----------------------------------------------------------------------------------------------- parsing helpers

def _load(path: Path) -> ET.Element:
    gc_was_enabled = gc.isenabled()
    try:
        raw = path.read_bytes()
        if raw[:2] == b"\x1f\x8b":
            raw = gzip.decompress(raw)
        # Speed: whitespace between tags (indentation) is dropped -- CommonRoad has no mixed content -- and the
        # cyclic garbage collector is paused while the tree is built (it would rescan the growing tree of
        # many small objects again and again); both make parsing several times faster (benchmarks/README.md).
        raw = _INDENT.sub(b"><", raw)
        gc.disable()
        root = ET.fromstring(raw)
    except (OSError, EOFError, zlib.error, ET.ParseError, ValueError) as exc:
        raise InputError(
            f"{path}: not a readable CommonRoad XML file ({exc}). "
            "Fix: re-export or re-download the file; gzip files must be complete."
        ) from None
    finally:
        if gc_was_enabled:
            gc.enable()
    if root.tag != "commonRoad":
        raise InputError(
            f"{path}: root element is <{root.tag}>, not <commonRoad>; this is not a CommonRoad scenario file. "
            "Fix: pass CommonRoad XML scenarios (.xml or .xml.gz) to the commonroad reader."
        )
    return root


def _float(text: str | None) -> float:
    if text is None:
        return _NAN
    try:
        return float(text)
    except ValueError:
        return _NAN


def _int(text: str | None) -> int:
    """A whole number of time steps; 0 when missing or not a finite number."""
    v = _float(text)
    return max(int(round(v)), 0) if math.isfinite(v) else 0


def _value(el: ET.Element | None) -> float:
    """A CommonRoad value element: <exact>, or the midpoint of <intervalStart>/<intervalEnd>."""
    if el is None:
        return _NAN
    exact = el.find("exact")
    if exact is not None:
        return _float(exact.text)
    return (_float(el.findtext("intervalStart")) + _float(el.findtext("intervalEnd"))) / 2


def _points(el: ET.Element | None) -> np.ndarray:
    if el is None:
        return np.empty((0, 2))
    pts = [(_float(p.findtext("x")), _float(p.findtext("y"))) for p in el.iterfind("point")]
    return np.array(pts, dtype=float).reshape(-1, 2)


def _wkt(g) -> str:
    return shapely.to_wkt(g, rounding_precision=_WKT_DIGITS)


# ---------------------------------------------------------------------------------------------------- tracks

def _size(obstacle: ET.Element) -> tuple[float | None, float | None]:
    shape = obstacle.find("shape")
    if shape is None:
        return None, None
    rect = shape.find("rectangle")
    if rect is not None:
        return _float(rect.findtext("length")), _float(rect.findtext("width"))
    circle = shape.find("circle")
    if circle is not None:
        d = 2 * _float(circle.findtext("radius"))
        return d, d
    return None, None


def _dynamic_obstacles(root: ET.Element) -> list[ET.Element]:
    legacy = [o for o in root.iterfind("obstacle") if (o.findtext("role") or "").strip() == "dynamic"]
    return legacy + root.findall("dynamicObstacle")


def _state_row(state: ET.Element) -> tuple[float, float, float, float, float, float]:
    """(time, x, y, orientation, velocity, acceleration) of a state; NaN where missing."""
    v = {"time": _NAN, "orientation": _NAN, "velocity": _NAN, "acceleration": _NAN}
    x = y = _NAN
    for child in state:  # one pass over the children: much faster than a find() per field
        tag = child.tag
        if tag == "position":
            point = child.find("point")
            if point is not None:
                x, y = _float(point.findtext("x")), _float(point.findtext("y"))
        elif tag in v:
            v[tag] = _value(child)
    return v["time"], x, y, v["orientation"], v["velocity"], v["acceleration"]


def _tracks(root: ET.Element, drive_id: str, dt: float) -> tuple[pl.DataFrame, int, int, str | None, int]:
    rows: list[tuple] = []
    seen = 0
    bad_ids: dict[str, int] = {}
    for ob in _dynamic_obstacles(root):
        actor = ob.get("id", "")
        kind = _KINDS.get((ob.findtext("type") or "").strip(), "object")
        length, width = _size(ob)
        states = [s for s in (ob.find("initialState"),) if s is not None] + ob.findall("trajectory/state")
        for st in states:
            seen += 1
            t, x, y, yaw, v, a = _state_row(st)
            if not all(math.isfinite(q) for q in (t, x, y, yaw, v)):
                bad_ids[actor] = bad_ids.get(actor, 0) + 1
                continue
            frame = int(round(t))
            rows.append((drive_id, actor, kind, False, frame, frame * dt, x, y, yaw, v,
                         a if math.isfinite(a) else None, length, width))
    tracks = pl.DataFrame(rows, schema=schema.TRACKS.polars_schema, orient="row")
    rejected = sum(bad_ids.values())
    reason = None
    if rejected:
        reason = (f"{rejected} state row(s) with a missing or non-finite x, y, orientation, velocity or time "
                  f"dropped (obstacle id(s): {', '.join(bad_ids)})")
    max_frame = int(tracks["frame"].max()) if tracks.height else 0
    return tracks, seen, rejected, reason, max_frame


# ------------------------------------------------------------------------------------------------------- map

def _resample(line: np.ndarray, n: int) -> np.ndarray:
    """``n`` points spaced evenly by arc length along the polyline (ends kept)."""
    seg = np.hypot(*np.diff(line, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return np.repeat(line[:1], n, axis=0)
    u = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(u, s, line[:, 0]), np.interp(u, s, line[:, 1])])


def _polygon(left: np.ndarray, right: np.ndarray) -> Polygon:
    """leftBound + reversed rightBound; repaired only when invalid, keeping the largest polygon part."""
    ring = np.vstack([left, right[::-1]])
    poly = Polygon(ring)
    if poly.is_valid and not poly.is_empty:
        return poly
    fixed = shapely.make_valid(poly)
    parts = shapely.get_parts(fixed)
    polys = [g for g in parts if isinstance(g, Polygon) and not g.is_empty]
    if polys:
        return max(polys, key=lambda g: g.area)
    # zero-area lanelet (both bounds on one line): a thin sliver around the bounds keeps it findable
    return LineString(ring).buffer(0.01)


def _centerline(left: np.ndarray, right: np.ndarray) -> LineString:
    """Pointwise midpoints of the bounds, both resampled by arc length to one point count if they differ."""
    if len(left) != len(right):
        n = max(len(left), len(right))
        left, right = _resample(left, n), _resample(right, n)
    return LineString((left + right) / 2)


def _neighbour(lanelet: ET.Element, tag: str) -> tuple[str | None, bool | None]:
    adj = lanelet.find(tag)
    if adj is None or adj.get("ref") is None:
        return None, None
    return adj.get("ref"), adj.get("drivingDir") == "same"


def _sign_speed_limits(root: ET.Element) -> dict[str, float]:
    """traffic sign id -> speed limit (m/s), for signs that carry a speed limit."""
    out: dict[str, float] = {}
    for sign in root.iterfind("trafficSign"):
        for el in sign.iterfind("trafficSignElement"):
            if (el.findtext("trafficSignID") or "").strip() in _SPEED_SIGNS:
                values = [_float(v.text) for v in el.iterfind("additionalValue")]
                values = [v for v in values if math.isfinite(v) and v > 0]
                sid = sign.get("id", "")
                if values:
                    out[sid] = min([*values, out.get(sid, math.inf)])
    return out


def _intersections(root: ET.Element) -> tuple[dict[str, str], dict[tuple[str, str], str], dict[str, list[str]]]:
    """junction lanelet -> intersection id; (incoming lanelet, successor) -> turn; intersection -> its lanelets."""
    junction_of: dict[str, str] = {}
    turn_of: dict[tuple[str, str], str] = {}
    members: dict[str, list[str]] = {}
    for inter in root.iterfind("intersection"):
        jid = inter.get("id", "")
        members[jid] = []
        for inc in inter.iterfind("incoming"):
            incoming = [e.get("ref") for e in inc.iterfind("incomingLanelet")]
            for tag, turn in _TURNS:
                for succ in (e.get("ref") for e in inc.iterfind(tag)):
                    junction_of.setdefault(succ, jid)
                    if succ not in members[jid]:
                        members[jid].append(succ)
                    for pred in incoming:
                        turn_of.setdefault((pred, succ), turn)
    return junction_of, turn_of, members


def _map(root: ET.Element, map_id: str, path: Path) -> tuple[pl.DataFrame, ...]:
    """lanes, lane_successors, junctions, traffic_lights of the file's lanelet network."""
    junction_of, turn_of, members = _intersections(root)
    sign_limits = _sign_speed_limits(root)
    lane_rows, succ_rows, light_rows = [], [], []
    polygons: dict[str, object] = {}
    light_pos: dict[str, tuple[float | None, float | None]] = {}
    light_dir: dict[str, str | None] = {}
    for light in root.iterfind("trafficLight"):
        pt = light.find("position/point")
        xy = (_float(pt.findtext("x")), _float(pt.findtext("y"))) if pt is not None else (_NAN, _NAN)
        light_pos[light.get("id", "")] = tuple(v if math.isfinite(v) else None for v in xy)
        light_dir[light.get("id", "")] = _DIRECTIONS.get((light.findtext("direction") or "all").strip())
    for ll in root.iterfind("lanelet"):
        lid = ll.get("id", "")
        left, right = _points(ll.find("leftBound")), _points(ll.find("rightBound"))
        if len(left) < 2 or len(right) < 2 or not (np.isfinite(left).all() and np.isfinite(right).all()):
            raise InputError(
                f"{path}: lanelet {lid} has a leftBound or rightBound with fewer than 2 points or a non-numeric "
                "coordinate; CommonRoad requires at least 2 points per bound. Fix: repair or re-export the map."
            )
        poly = _polygon(left, right)
        polygons[lid] = poly
        left_id, left_same = _neighbour(ll, "adjacentLeft")
        right_id, right_same = _neighbour(ll, "adjacentRight")
        limit = _float(ll.findtext("speedLimit"))
        if not math.isfinite(limit):
            refs = [sign_limits[r.get("ref")] for r in ll.iterfind("trafficSignRef") if r.get("ref") in sign_limits]
            limit = min(refs) if refs else _NAN
        lane_type = ll.findtext("laneletType")
        lane_rows.append((
            map_id, lid, lane_type.strip() if lane_type else None, _wkt(poly), _wkt(_centerline(left, right)),
            left_id, left_same, right_id, right_same, limit if math.isfinite(limit) else None, junction_of.get(lid),
        ))
        succ_rows += [(map_id, lid, s.get("ref"), turn_of.get((lid, s.get("ref"))))
                      for s in ll.iterfind("successor") if s.get("ref") is not None]
        refs = [r.get("ref") for r in (*ll.iterfind("trafficLightRef"), *ll.iterfind("stopLine/trafficLightRef"))]
        for ref in dict.fromkeys(r for r in refs if r is not None):
            x, y = light_pos.get(ref, (None, None))
            light_rows.append((map_id, ref, lid, light_dir.get(ref), x, y))
    junction_rows = []
    for jid, lanelets in members.items():
        geoms = [polygons[lid] for lid in lanelets if lid in polygons]
        if geoms:
            junction_rows.append((map_id, jid, _wkt(shapely.union_all(geoms))))
    return (
        pl.DataFrame(lane_rows, schema=schema.LANES.polars_schema, orient="row"),
        pl.DataFrame(succ_rows, schema=schema.LANE_SUCCESSORS.polars_schema, orient="row"),
        pl.DataFrame(junction_rows, schema=schema.JUNCTIONS.polars_schema, orient="row"),
        pl.DataFrame(light_rows, schema=schema.TRAFFIC_LIGHTS.polars_schema, orient="row"),
    )


# --------------------------------------------------------------------------------------------- light states

def light_state(durations: list[int], colours: list[str], offset: int, frame: int) -> str:
    """State at ``frame`` of a cycle that starts at time step ``offset`` (see the module docstring)."""
    total = sum(durations)
    if total <= 0:
        return "unknown"
    p = (frame - offset) % total
    for duration, colour in zip(durations, colours, strict=False):
        if p < duration:
            return colour
        p -= duration
    return "unknown"  # pragma: no cover - p < total always hits an element


def _light_states(root: ET.Element, drive_id: str, max_frame: int) -> pl.DataFrame:
    rows: list[tuple] = []
    frames = range(max_frame + 1)
    for light in root.iterfind("trafficLight"):
        cycle = light.find("cycle")
        if cycle is None:
            continue
        lid = light.get("id", "")
        if (light.findtext("active") or "true").strip().lower() == "false":
            rows += [(drive_id, lid, k, "off") for k in frames]
            continue
        elements = cycle.findall("cycleElement")
        durations = [_int(e.findtext("duration")) for e in elements]
        colours = [_COLOURS.get((e.findtext("color") or "").strip(), "unknown") for e in elements]
        offset = _float(cycle.findtext("timeOffset"))
        offset = int(round(offset)) if math.isfinite(offset) else 0
        rows += [(drive_id, lid, k, light_state(durations, colours, offset, k)) for k in frames]
    return pl.DataFrame(rows, schema=schema.TRAFFIC_LIGHT_STATES.polars_schema, orient="row")


# ------------------------------------------------------------------------------------------------------ entry

def read_commonroad(path: str | Path) -> list[DriveData]:
    """Read one CommonRoad scenario file (``.xml`` or ``.xml.gz``) into one drive."""
    path = Path(path)
    root = _load(path)
    benchmark = root.get("benchmarkID")
    version = root.get("commonRoadVersion")
    if not benchmark or not version:
        missing = " and ".join(a for a, v in (("benchmarkID", benchmark), ("commonRoadVersion", version)) if not v)
        raise InputError(f"{path}: the <commonRoad> element has no {missing} attribute.")
    dt = _float(root.get("timeStepSize"))
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(
            f"{path}: timeStepSize is {root.get('timeStepSize')!r}; it must be a positive number of seconds."
        )
    drive_id = f"{benchmark}@{version}"
    tracks, seen, rejected, reason, max_frame = _tracks(root, drive_id, dt)
    lanes, successors, junctions, lights = _map(root, drive_id, path)
    return [DriveData(
        drive_id=drive_id, source_format="commonroad", source_path=str(path), dt_s=dt, tracks=tracks,
        map_id=drive_id, lanes=lanes, lane_successors=successors, junctions=junctions, traffic_lights=lights,
        traffic_light_states=_light_states(root, drive_id, max_frame), ego_actor_id=None,
        rows_read=seen, rows_rejected=rejected, reject_reason=reason, attribution=ATTRIBUTION,
    )]
