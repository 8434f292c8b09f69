"""OpenSCENARIO 1.3 export of one match: the ego and the actor replay their recorded trajectories.

Mapping (docs/formats.md):
    Entities: ``ego`` and ``actor`` (names in the file), each a Vehicle, Pedestrian or MiscObject by kind
    (``ENTITY``), with the box of its first row of the match (height by kind, ``HEIGHT_M``). The reference point
    of each entity is the box centre on the ground: BoundingBox Center (0, 0, height/2), rear axle at x = 0, so
    the recorded centre is the position a simulator places.
    Init: both teleported to their position and heading at the match's start (WorldPosition x, y, h).
    Story: one maneuver group per entity with a FollowTrajectoryAction: a Polyline with one timed Vertex per
    recorded frame from start_frame to end_frame (time = t_s - start_s, WorldPosition x, y, h), absolute timing,
    following mode ``position``; it starts at simulation time 0. The storyboard stops at the match's duration.
    RoadNetwork: LogicFile = the drive's OpenDRIVE map when it came from an .xodr (path relative to the .xosc);
    with ``convert_map``, a SUMO drive's network converted to OpenDRIVE beside the .xosc; for other maps
    (CommonRoad, ...) no LogicFile: the FileHeader description names the map_id instead.
"""

from __future__ import annotations

import datetime
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.opendrive import netconvert
from logiq_sql.ingestion.readers.sumo import network_of
from logiq_sql.outputs.export import OPENSCENARIO_XSD, open_db, xodr_file

# kind -> (entity element, category attribute, category)
ENTITY = {
    **dict.fromkeys(("vehicle", "stationary_vehicle", "emergency_vehicle"), ("Vehicle", "vehicleCategory", "car")),
    "truck": ("Vehicle", "vehicleCategory", "truck"), "trailer": ("Vehicle", "vehicleCategory", "trailer"),
    "bus": ("Vehicle", "vehicleCategory", "bus"), "motorcycle": ("Vehicle", "vehicleCategory", "motorbike"),
    "cyclist": ("Vehicle", "vehicleCategory", "bicycle"),
    "person": ("Pedestrian", "pedestrianCategory", "pedestrian"),
    "animal": ("Pedestrian", "pedestrianCategory", "animal"),
    **dict.fromkeys(("object", "fod", "sign"), ("MiscObject", "miscObjectCategory", "obstacle")),
}
HEIGHT_M = {"truck": 3.5, "trailer": 3.5, "bus": 3.2, "person": 1.75, "animal": 1.0, "cyclist": 1.7,
            "motorcycle": 1.5, "object": 1.0, "fod": 0.3, "sign": 2.5}
DEFAULT_HEIGHT_M = 1.5
MASS_KG = {"Pedestrian": 80.0, "MiscObject": 100.0}
# generous limits: a replayed trajectory must never be clipped by the entity's performance
MAX_SPEED_MPS, MAX_ACCEL_MPS2 = 100.0, 20.0
REV = (1, 3)


@dataclass
class XoscExport:
    path: Path
    match_id: str
    vertices: dict[str, int]
    map_reference: str


def _num(x: float) -> str:
    return f"{x:.4f}".rstrip("0").rstrip(".") if x == x else "0"


def _el(parent: ET.Element, tag: str, **attrs) -> ET.Element:
    return ET.SubElement(parent, tag, {k: v if isinstance(v, str) else _num(v) for k, v in attrs.items()})


def _world(parent: ET.Element, row: dict) -> None:
    _el(_el(parent, "Position"), "WorldPosition", x=row["x_m"], y=row["y_m"], h=row["heading_rad"] or 0.0)


def _time_trigger(parent: ET.Element, tag: str, name: str, rule: str, value: float) -> None:
    condition = _el(_el(_el(parent, tag), "ConditionGroup"), "Condition", name=name, delay=0.0, conditionEdge="none")
    _el(_el(condition, "ByValueCondition"), "SimulationTimeCondition", value=value, rule=rule)


def _entity(entities: ET.Element, name: str, first: dict) -> None:
    element, category_attr, category = ENTITY.get(first["kind"], ENTITY["object"])
    obj = _el(entities, "ScenarioObject", name=name)
    attrs = {"name": f"{first['kind']} {first['actor_id']}", category_attr: category}
    if element != "Vehicle":
        attrs["mass"] = MASS_KG[element]
    entity = _el(obj, element, **attrs)
    height = HEIGHT_M.get(first["kind"], DEFAULT_HEIGHT_M)
    box = _el(entity, "BoundingBox")
    _el(box, "Center", x=0.0, y=0.0, z=height / 2)
    _el(box, "Dimensions", width=first["width_m"], length=first["length_m"], height=height)
    if element == "Vehicle":
        _el(entity, "Performance", maxSpeed=MAX_SPEED_MPS, maxAcceleration=MAX_ACCEL_MPS2,
            maxDeceleration=MAX_ACCEL_MPS2)
        axles = _el(entity, "Axles")
        _el(axles, "RearAxle", maxSteering=0.0, wheelDiameter=0.6, trackWidth=first["width_m"], positionX=0.0,
            positionZ=0.3)
    _el(entity, "Properties")


def _follow(story: ET.Element, name: str, rows: list[dict], start_s: float) -> None:
    group = _el(story, "ManeuverGroup", maximumExecutionCount="1", name=f"{name}_group")
    _el(_el(group, "Actors", selectTriggeringEntities="false"), "EntityRef", entityRef=name)
    event = _el(_el(group, "Maneuver", name=f"{name}_replay"), "Event", name=f"{name}_follow", priority="override")
    action = _el(_el(_el(event, "Action", name=f"{name}_trajectory"), "PrivateAction"), "RoutingAction")
    follow = _el(action, "FollowTrajectoryAction")
    trajectory = _el(_el(follow, "TrajectoryRef"), "Trajectory", name=f"{name}_recorded", closed="false")
    polyline = _el(_el(trajectory, "Shape"), "Polyline")
    for row in rows:
        _world(_el(polyline, "Vertex", time=row["t_s"] - start_s), row)
    _el(_el(follow, "TimeReference"), "Timing", domainAbsoluteRelative="absolute", scale=1.0, offset=0.0)
    _el(follow, "TrajectoryFollowingMode", followingMode="position")
    _time_trigger(event, "StartTrigger", f"{name}_at_start", "greaterOrEqual", 0.0)


def export_xosc(db_path: str | Path, match_id: str, out: str | Path, convert_map: bool = False) -> XoscExport:
    """Write the OpenSCENARIO file of one match. ``convert_map``: a drive on a SUMO network gets that network
    written as OpenDRIVE beside the .xosc (netconvert) and referenced."""
    out = Path(out)
    with open_db(db_path) as con:
        found = con.execute(
            "select m.scenario, m.drive_id, m.ego_id, m.actor_id, m.start_frame, m.end_frame, m.start_s, m.end_s, "
            "d.map_id, d.source_path from matches m join drive_inputs d using (drive_id) where m.match_id = $id",
            {"id": match_id}).fetchall()
        if not found:
            raise InputError(f"match_id '{match_id}': no such match in {db_path}. Fix: pick one with "
                             f"logiq-sql query --db {db_path} \"select match_id, scenario, drive_id from matches\".")
        scenario, drive, ego, actor, start_f, end_f, start_s, end_s, map_id, source = found[0]
        tracks = con.sql(
            "select actor_id, kind, frame, t_s, x_m, y_m, heading_rad, length_m, width_m from tracks "
            "where drive_id = $d and actor_id in ($e, $a) and frame between $s and $f order by actor_id, frame",
            params={"d": drive, "e": ego, "a": actor, "s": start_f, "f": end_f}).pl()
    rows = {who: tracks.filter(pl.col("actor_id") == aid).to_dicts() for who, aid in (("ego", ego), ("actor", actor))}
    for who, aid in (("ego", ego), ("actor", actor)):
        if len(rows[who]) < 2:
            raise InputError(f"match '{match_id}': the {who} '{aid}' has {len(rows[who])} track row(s) in frames "
                             f"{start_f}..{end_f} of drive '{drive}'; a trajectory needs two. Fix: re-ingest the "
                             "drive and rerun match.")
    xodr = xodr_file(map_id, source)
    map_note = (f"map: OpenDRIVE {xodr.name}" if xodr else
                f"map: {map_id or 'none'} (not an OpenDRIVE file; no LogicFile)")
    if xodr is None and convert_map:
        xodr, map_note = _sumo_map_as_xodr(map_id, Path(source), out) or (None, map_note)
    root = ET.Element("OpenSCENARIO")
    _el(root, "FileHeader", revMajor=str(REV[0]), revMinor=str(REV[1]), author="logiq-sql",
        date=datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat(),
        description=f"{scenario} match {match_id}: drive {drive}, ego {ego}, actor {actor}, "
                    f"t {start_s:g}..{end_s:g} s; {map_note}")
    _el(root, "CatalogLocations")
    network = _el(root, "RoadNetwork")
    reference = ""
    if xodr is not None:
        reference = os.path.relpath(xodr.resolve(), out.resolve().parent)
        _el(network, "LogicFile", filepath=reference)
    entities = _el(root, "Entities")
    for who in ("ego", "actor"):
        _entity(entities, who, rows[who][0])
    storyboard = _el(root, "Storyboard")
    init = _el(_el(storyboard, "Init"), "Actions")
    for who in ("ego", "actor"):
        teleport = _el(_el(_el(init, "Private", entityRef=who), "PrivateAction"), "TeleportAction")
        _world(teleport, rows[who][0])
    act = _el(_el(storyboard, "Story", name=scenario), "Act", name="replay")
    for who in ("ego", "actor"):
        _follow(act, who, rows[who], start_s)
    _time_trigger(act, "StartTrigger", "at_start", "greaterOrEqual", 0.0)
    _time_trigger(storyboard, "StopTrigger", "match_end", "greaterThan", end_s - start_s)
    ET.indent(root)
    out.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(out, encoding="utf-8", xml_declaration=True)
    return XoscExport(out, match_id, {who: len(rows[who]) for who in rows}, reference or map_note)


def _sumo_map_as_xodr(map_id: str | None, run: Path, out: Path) -> tuple[Path, str] | None:
    """A SUMO drive's network written as OpenDRIVE beside ``out``; netconvert keeps the network's coordinates, the
    frame of the drive's tracks. None when the drive's map is not a SUMO network still in its run folder."""
    net = network_of(map_id, run) if map_id and map_id.startswith("sumo-") else None
    if net is None:
        return None
    xodr = out.with_suffix(".xodr")
    out.parent.mkdir(parents=True, exist_ok=True)
    netconvert(["--sumo-net-file", str(net), "--opendrive-output", str(xodr)], net, "write the network as OpenDRIVE",
               "check that the network opens in SUMO (sumo-gui).")
    return xodr, f"map: OpenDRIVE {xodr.name}, converted by netconvert from the SUMO network {net} ({map_id})"


def validate_xosc(path: str | Path) -> None:
    """Raise when the file is not valid against the OpenSCENARIO 1.3.1 XSD (needs the [formats] extra)."""
    import xmlschema

    xmlschema.XMLSchema(str(OPENSCENARIO_XSD)).validate(str(path))
