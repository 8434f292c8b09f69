"""ASAM OSI traces: one trace file is one drive, decoded with the ASAM OSI Python bindings (``osi3``, PyPI
``osi-python``, in the ``[formats]`` extra).

Files
    ``.osi``: OSI's single-channel binary trace, each message a 4-byte little-endian length then the serialized
    message. The message type is ``osi3.GroundTruth`` or ``osi3.SensorView`` (whose ``global_ground_truth`` is
    read, with the view's ``host_vehicle_id`` and ``timestamp`` where the ground truth has none): from the OSI
    trace-file naming convention (``..._gt_...`` / ``..._sv_...`` in the file name), else the first message
    decides (SensorView if it parses as one holding moving objects, else GroundTruth).
    ``.mcap``: every message of the channels whose schema is ``osi3.GroundTruth`` or ``osi3.SensorView``.
    A truncated or undecodable message rejects the whole file, naming the message and its byte offset: nothing of
    it is written.

Drive
    drive_id = the file name without ``.osi`` / ``.mcap``; t_s = the message timestamp (seconds + nanos) minus the
    first message's; dt_s = the median step between timestamps; frame = round(t_s / dt_s). The ego
    (``is_ego``, ``ego_actor_id``) is ``host_vehicle_id``.

Tracks, one row per ``moving_object`` per message
    actor_id = ``id.value``; x_m, y_m = ``base.position`` (OSI: the centre of the bounding box, in the global
    frame); heading_rad = ``base.orientation.yaw``; speed_mps and accel_mps2 = ``base.velocity`` and
    ``base.acceleration`` (global vectors) projected on the heading (NULL when the message has no such vector or
    no orientation: derived at ingest); length_m, width_m = ``base.dimension`` (NULL when 0 or absent: the kind's default).
    kind (``kind_of``): TYPE_PEDESTRIAN -> person, TYPE_ANIMAL -> animal, TYPE_OTHER / TYPE_UNKNOWN -> object;
    TYPE_VEHICLE by ``vehicle_classification.type`` (``VEHICLE_KINDS``), and a vehicle whose role is ambulance,
    fire or police -> emergency_vehicle. Stationary objects, lanes and signals of the trace are not read.

Map
    OSI traces carry OpenDRIVE maps by reference: the ``.xodr`` that ``map_reference`` names, when that file lies
    beside the trace; else, when ``map_reference`` is empty, the one ``.xodr`` beside the trace. It is read as in
    ``logiq_sql.ingestion.readers.opendrive`` (positions in OSI's global frame are the OpenDRIVE inertial frame). Otherwise
    the drive has no map.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.base import DriveData
from logiq_sql.ingestion.readers.opendrive import with_map, xodr_map

ATTRIBUTION = "ASAM OSI trace; licence as given by its provider"

VEHICLE_KINDS = {
    **dict.fromkeys(("TYPE_UNKNOWN", "TYPE_OTHER", "TYPE_SMALL_CAR", "TYPE_COMPACT_CAR", "TYPE_CAR",
                     "TYPE_MEDIUM_CAR", "TYPE_LUXURY_CAR", "TYPE_DELIVERY_VAN", "TYPE_VAN", "TYPE_LAND_VEHICLE"),
                    "vehicle"),
    "TYPE_HEAVY_TRUCK": "truck", "TYPE_SEMITRACTOR": "truck", "TYPE_SEMITRAILER": "trailer", "TYPE_TRAILER": "trailer",
    "TYPE_MOTORBIKE": "motorcycle", "TYPE_MOTORCYCLE": "motorcycle", "TYPE_BICYCLE": "cyclist",
    "TYPE_STANDUP_SCOOTER": "cyclist", "TYPE_MICROMOBILITY_DEVICE": "cyclist", "TYPE_BUS": "bus",
    "TYPE_WHEELCHAIR": "person",
    **dict.fromkeys(("TYPE_TRAM", "TYPE_TRAIN", "TYPE_WORK_MACHINE", "TYPE_WATERCRAFT", "TYPE_AIRCRAFT"), "object"),
}
OBJECT_KINDS = {"TYPE_PEDESTRIAN": "person", "TYPE_ANIMAL": "animal", "TYPE_OTHER": "object", "TYPE_UNKNOWN": "object"}
EMERGENCY_ROLES = ("ROLE_AMBULANCE", "ROLE_FIRE", "ROLE_POLICE")
_HEADER = struct.Struct("<L")
_RAW = {"id": pl.UInt64, "kind": pl.String, "t_ns": pl.Int64, "x_m": pl.Float64, "y_m": pl.Float64,
        "heading_rad": pl.Float64, "vx": pl.Float64, "vy": pl.Float64, "ax": pl.Float64, "ay": pl.Float64,
        "length_m": pl.Float64, "width_m": pl.Float64}


def _osi3():
    try:
        from osi3 import osi_groundtruth_pb2, osi_object_pb2, osi_sensorview_pb2
    except ImportError:
        raise InputError("reading ASAM OSI traces needs the OSI bindings. Fix: pip install 'logiq-sql[formats]'.") \
            from None
    return osi_groundtruth_pb2.GroundTruth, osi_sensorview_pb2.SensorView, osi_object_pb2.MovingObject


def kind_of(obj) -> str:
    """The evaluation_object_kind of an ``osi3.MovingObject``."""
    moving = type(obj)
    object_type = moving.Type.Name(obj.type)
    if object_type != "TYPE_VEHICLE":
        return OBJECT_KINDS.get(object_type, "object")
    vc = obj.vehicle_classification
    if moving.VehicleClassification.Role.Name(vc.role) in EMERGENCY_ROLES:
        return "emergency_vehicle"
    return VEHICLE_KINDS.get(moving.VehicleClassification.Type.Name(vc.type), "vehicle")


# ------------------------------------------------------------------------------------------------- messages

def _osi_messages(path: Path) -> Iterator[tuple[int, bytes]]:
    """(byte offset, serialized message) of a single-channel .osi trace."""
    try:
        with open(path, "rb") as f:
            offset = 0
            while header := f.read(_HEADER.size):
                if len(header) < _HEADER.size:
                    raise InputError(f"{path}: {len(header)} stray byte(s) at byte {offset}, not a 4-byte length "
                                     "prefix; the trace is truncated or not an OSI trace. Fix: copy or record it "
                                     "again.")
                (size,) = _HEADER.unpack(header)
                body = f.read(size)
                if len(body) < size:
                    raise InputError(f"{path}: the message at byte {offset} is cut off ({len(body)} of the {size} "
                                     "bytes its length prefix gives); the trace is truncated. Fix: copy or record "
                                     "it again (the recorder must finish writing it).")
                yield offset, body
                offset += _HEADER.size + size
    except OSError as exc:
        raise InputError(f"{path}: not readable ({exc}).") from None


def _mcap_messages(path: Path) -> Iterator[tuple[str, int, bytes]]:
    """(schema name, log time, serialized message) of the OSI channels of an MCAP file."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            for schema_, _, message in make_reader(f).iter_messages():
                if schema_ is not None and schema_.name in ("osi3.GroundTruth", "osi3.SensorView"):
                    yield schema_.name, message.log_time, message.data
    except InputError:
        raise
    except Exception as exc:  # the mcap reader raises its own types for broken files
        raise InputError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc}). Fix: copy or record "
                         "it again.") from None


def _ground_truths(path: Path) -> Iterator[tuple[str, object]]:
    """(where, osi3.GroundTruth) of every message of the trace."""
    from google.protobuf.message import DecodeError

    ground_truth, sensor_view, _ = _osi3()

    def decode(cls, body: bytes, where: str):
        msg = cls()
        try:
            msg.ParseFromString(body)
        except DecodeError as exc:
            raise InputError(f"{path}: {where} is not a valid osi3.{cls.__name__} ({exc}); the trace is corrupt. "
                             "Fix: copy or record it again.") from None
        if cls is not sensor_view:
            return msg
        gt = msg.global_ground_truth  # the view's own host and time stand where its ground truth has none
        for name in ("host_vehicle_id", "timestamp"):
            if msg.HasField(name) and not gt.HasField(name):
                getattr(gt, name).CopyFrom(getattr(msg, name))
        return gt

    if path.suffix.lower() == ".mcap":
        for i, (name, _, body) in enumerate(_mcap_messages(path)):
            cls = sensor_view if name == "osi3.SensorView" else ground_truth
            yield f"message {i}", decode(cls, body, f"message {i}")
        return
    parts = path.stem.lower().split("_")
    cls = sensor_view if "sv" in parts else ground_truth if "gt" in parts else None
    for i, (offset, body) in enumerate(_osi_messages(path)):
        where = f"message {i} (byte {offset})"
        if cls is None:
            cls = sensor_view if _is_sensor_view(sensor_view, body) else ground_truth
        yield where, decode(cls, body, where)


def _is_sensor_view(sensor_view, body: bytes) -> bool:
    from google.protobuf.message import DecodeError

    msg = sensor_view()
    try:
        msg.ParseFromString(body)
    except DecodeError:
        return False
    return len(msg.global_ground_truth.moving_object) > 0


# ---------------------------------------------------------------------------------------------------- drive

def read_osi(path: str | Path) -> Iterator[DriveData]:
    """One drive per OSI trace file."""
    path = Path(path)
    cols: dict[str, list] = {c: [] for c in _RAW}
    put = [cols[c].append for c in _RAW]  # bound appends: the loop below runs once per object and message
    hosts: set[str] = set()
    map_reference = ""
    messages = 0
    kinds: dict[tuple[int, int, int], str] = {}  # (type, classification type, role) -> kind, looked up once
    # protobuf messages decode one at a time: this loop is the decoder; projections and the rest are set-based
    for where, gt in _ground_truths(path):
        messages += 1
        if not gt.HasField("timestamp"):
            raise InputError(f"{path}: {where} has no timestamp. Fix: record the trace with timestamps.")
        t_ns = gt.timestamp.seconds * 1_000_000_000 + gt.timestamp.nanos
        if gt.HasField("host_vehicle_id"):
            hosts.add(str(gt.host_vehicle_id.value))
        map_reference = map_reference or gt.map_reference
        for obj in gt.moving_object:
            base, vc = obj.base, obj.vehicle_classification
            key = (obj.type, vc.type, vc.role)
            v = (base.velocity.x, base.velocity.y) if base.HasField("velocity") else (None, None)
            a = (base.acceleration.x, base.acceleration.y) if base.HasField("acceleration") else (None, None)
            for append, value in zip(put, (
                    obj.id.value, kinds.get(key) or kinds.setdefault(key, kind_of(obj)), t_ns, base.position.x,
                    base.position.y, base.orientation.yaw if base.HasField("orientation") else None, *v, *a,
                    base.dimension.length, base.dimension.width), strict=True):
                append(value)
    if not messages:
        raise InputError(f"{path}: no OSI GroundTruth or SensorView message. Fix: pass a trace that has them.")
    if len(hosts) > 1:
        raise InputError(f"{path}: host_vehicle_id changes within the trace ({', '.join(sorted(hosts)[:5])}); a "
                         "drive has one ego. Fix: split the trace per host vehicle.")
    raw = pl.DataFrame(cols, schema=_RAW)
    del cols, put
    yaw = pl.col("heading_rad")

    def along(x: str, y: str) -> pl.Expr:  # a global vector projected on the heading (NULL when either is absent)
        return pl.col(x) * yaw.cos() + pl.col(y) * yaw.sin()

    rows = raw.select(
        pl.col("id").cast(pl.String).alias("actor_id"), "kind", "t_ns", "x_m", "y_m", "heading_rad",
        along("vx", "vy").alias("speed_mps"), along("ax", "ay").alias("accel_mps2"),
        *[pl.when(pl.col(c) > 0).then(pl.col(c)).alias(c) for c in ("length_m", "width_m")])
    steps = rows["t_ns"].unique().sort().diff().drop_nulls()
    steps = steps.filter(steps > 0)
    if steps.is_empty():
        raise InputError(f"{path}: fewer than two timestamps with moving objects; the sample period is unknown. "
                         "Fix: record a longer trace.")
    dt_s = round(float(steps.median()) / 1e9, 9)
    ego = next(iter(hosts), None)
    drive_id = path.name.removesuffix(path.suffix)
    t_s = (pl.col("t_ns") - pl.col("t_ns").min()) / 1e9
    tracks = rows.select(
        pl.lit(drive_id).alias("drive_id"), "actor_id", "kind", (pl.col("actor_id") == pl.lit(ego)).fill_null(False)
        .alias("is_ego"), (t_s / dt_s).round().cast(pl.Int64).alias("frame"), t_s.alias("t_s"), "x_m", "y_m",
        "heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m",
    ).cast(schema.TRACKS.polars_schema)
    drive = DriveData(drive_id=drive_id, source_format="osi", source_path=str(path), dt_s=dt_s, tracks=tracks,
                      ego_actor_id=ego, rows_read=tracks.height, attribution=ATTRIBUTION)
    xodr = _map_file(path, map_reference)
    if xodr is not None:
        drive = with_map(drive, *xodr_map(xodr))
    yield drive


def _map_file(path: Path, map_reference: str) -> Path | None:
    if map_reference:
        named = path.parent / Path(map_reference.replace("\\", "/")).name
        return named if named.is_file() else None
    maps = sorted(path.parent.glob("*.xodr"))
    return maps[0] if len(maps) == 1 else None
