"""ASAM OSI traces in (issue 20): traces written in the test with the OSI bindings (osi3), read back as tracks."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import ingest
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.osi import read_osi

osi_object = pytest.importorskip("osi3.osi_object_pb2", reason="pip install 'logiq-sql[formats]'")
from osi3.osi_groundtruth_pb2 import GroundTruth  # noqa: E402
from osi3.osi_sensorview_pb2 import SensorView  # noqa: E402

MO = osi_object.MovingObject
VC = MO.VehicleClassification
STEPS, DT_S, T0_S = 30, 0.05, 1000.0  # 30 messages, 20 Hz, a clock that does not start at 0
EGO_YAW = 0.5


def _ground_truth(i: int, map_reference: str = "") -> GroundTruth:
    gt = GroundTruth()
    t_ns = round((T0_S + i * DT_S) * 1e9)
    gt.timestamp.seconds, gt.timestamp.nanos = divmod(t_ns, 1_000_000_000)
    gt.host_vehicle_id.value = 1
    gt.map_reference = map_reference

    def add(oid, otype, x, y, yaw, v, size, vclass=None, role=None, velocity=True, orientation=True):
        mo = gt.moving_object.add()
        mo.id.value = oid
        mo.type = otype
        if vclass is not None:
            mo.vehicle_classification.type = vclass
        if role is not None:
            mo.vehicle_classification.role = role
        b = mo.base
        b.position.x, b.position.y = x, y
        if orientation:
            b.orientation.yaw = yaw
        b.dimension.length, b.dimension.width, b.dimension.height = size
        if velocity:
            b.velocity.x, b.velocity.y = v * math.cos(yaw), v * math.sin(yaw)
            b.acceleration.x, b.acceleration.y = 0.5 * math.cos(yaw), 0.5 * math.sin(yaw)

    t = i * DT_S
    add(1, MO.TYPE_VEHICLE, 100 + 10 * t * math.cos(EGO_YAW), 200 + 10 * t * math.sin(EGO_YAW), EGO_YAW, 10.0,
        (4.6, 1.9, 1.5), VC.TYPE_MEDIUM_CAR)
    add(2, MO.TYPE_VEHICLE, 130 + 8 * t, 200.0, 0.0, 8.0, (12.0, 2.5, 3.0), VC.TYPE_BUS)
    add(3, MO.TYPE_PEDESTRIAN, 90.0, 190 + 1.2 * t, math.pi / 2, 1.2, (0.5, 0.6, 1.8), velocity=False)
    add(4, MO.TYPE_VEHICLE, 60 - 15 * t, 210.0, math.pi, 15.0, (0, 0, 0), VC.TYPE_CAR, VC.ROLE_POLICE)
    add(5, MO.TYPE_ANIMAL, 70.0 + 2 * t, 230.0, 0.0, 2.0, (1.0, 0.4, 0.8), orientation=False)
    return gt


def _write(path: Path, messages) -> Path:
    with open(path, "wb") as f:
        for m in messages:
            body = m.SerializeToString()
            f.write(struct.pack("<L", len(body)) + body)
    return path


def _gt_trace(path: Path, **kw) -> Path:
    return _write(path, (_ground_truth(i, **kw) for i in range(STEPS)))


def test_a_ground_truth_trace_becomes_tracks(tmp_path):
    (drive,) = read_osi(_gt_trace(tmp_path / "drive_a.osi"))
    tracks = drive.tracks.sort("actor_id", "frame")
    assert (drive.drive_id, drive.source_format, drive.ego_actor_id) == ("drive_a", "osi", "1")
    assert drive.dt_s == pytest.approx(DT_S) and tracks.height == 5 * STEPS
    by_actor = {a: rows for (a,), rows in tracks.group_by("actor_id")}
    ego = by_actor["1"].sort("frame")
    assert ego["is_ego"].all() and not tracks.filter(pl.col("actor_id") != "1")["is_ego"].any()
    assert ego["frame"].to_list() == list(range(STEPS))
    assert ego["t_s"].to_list() == pytest.approx([i * DT_S for i in range(STEPS)])
    assert ego["x_m"][10] == pytest.approx(100 + 10 * 0.5 * math.cos(EGO_YAW))
    assert ego["y_m"][10] == pytest.approx(200 + 10 * 0.5 * math.sin(EGO_YAW))
    assert ego["heading_rad"].to_list() == pytest.approx([EGO_YAW] * STEPS)
    assert ego["speed_mps"].to_list() == pytest.approx([10.0] * STEPS)  # the velocity vector along the heading
    assert ego["accel_mps2"].to_list() == pytest.approx([0.5] * STEPS)
    assert (ego["length_m"][0], ego["width_m"][0]) == pytest.approx((4.6, 1.9))
    kinds = {a: rows["kind"][0] for a, rows in by_actor.items()}
    assert kinds == {"1": "vehicle", "2": "bus", "3": "person", "4": "emergency_vehicle", "5": "animal"}
    walker, police = by_actor["3"], by_actor["4"]
    assert walker["speed_mps"].is_null().all()  # no velocity in the message: derived at ingest
    assert police["length_m"].is_null().all()  # dimension 0: the kind's default at ingest
    assert police["speed_mps"][0] == pytest.approx(15.0)  # heading pi, velocity -x: forward
    animal = by_actor["5"]  # a velocity but no orientation: heading and speed unknown, derived at ingest
    assert animal["heading_rad"].is_null().all() and animal["speed_mps"].is_null().all()


def test_a_sensor_view_trace_reads_its_global_ground_truth(tmp_path):
    def views():
        for i in range(STEPS):
            sv = SensorView()
            sv.global_ground_truth.CopyFrom(_ground_truth(i))
            sv.timestamp.CopyFrom(sv.global_ground_truth.timestamp)
            sv.host_vehicle_id.value = 1
            sv.global_ground_truth.ClearField("host_vehicle_id")  # the view names the host: still the ego
            yield sv

    # named by the OSI convention (_sv_) and not: the content decides then
    for name in ("20260101T000000Z_sv_380_3300_30_run.osi", "plain.osi"):
        (drive,) = read_osi(_write(tmp_path / name, views()))
        (want,) = read_osi(_gt_trace(tmp_path / "ref.osi"))
        assert drive.tracks.drop("drive_id").equals(want.tracks.drop("drive_id")), name


def test_ingest_accounts_for_good_truncated_and_corrupt_traces(tmp_path):
    folder = tmp_path / "traces"
    folder.mkdir()
    _gt_trace(folder / "good.osi")
    cut = _gt_trace(folder / "cut.osi")
    cut.write_bytes(cut.read_bytes()[:-40])
    bad = folder / "garbage.osi"
    body = b"\xff" * 64
    bad.write_bytes(struct.pack("<L", len(body)) + body)
    with pytest.raises(InputError, match=r"cut.osi: the message at byte \d+ is cut off \(\d+ of the \d+ bytes"):
        list(read_osi(cut))
    with pytest.raises(InputError, match=r"garbage.osi: message 0 \(byte 0\) is not a valid osi3.GroundTruth"):
        list(read_osi(bad))
    db = tmp_path / "osi.duckdb"
    summary = ingest("osi", [folder], db)
    assert (summary.drives, summary.rejected) == (1, 2)
    with duckdb.connect(str(db), read_only=True) as con:
        drives = {r[0]: r[1:] for r in con.sql(
            "select drive_id, status, ego_actor_id, reject_reason from drive_inputs").fetchall()}
        per_drive = dict(con.sql("select drive_id, count(*) from tracks group by 1").fetchall())
        statuses = dict(con.sql("select drive_id, status from drives").fetchall())
    assert drives["good"][:2] == ("ingested", "1")
    assert drives["cut"][0] == drives["garbage"][0] == "rejected"
    assert str(cut) in drives["cut"][2] and str(bad) in drives["garbage"][2]
    assert per_drive == {"good": 5 * STEPS}  # nothing of the broken traces was written
    assert statuses == {"good": "not_matched", "cut": "rejected", "garbage": "rejected"}


def test_the_map_the_trace_references_is_read(tmp_path):
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    xodr = pytest.importorskip("scenariogeneration.xodr")
    road = xodr.create_road(xodr.Line(300), id=1, left_lanes=1, right_lanes=2, lane_width=3.5)
    # the reference line passes 1.75 m left of the ego's start: the ego drives in the inner right lane (-1_1)
    right, along = (math.sin(EGO_YAW), -math.cos(EGO_YAW)), (math.cos(EGO_YAW), math.sin(EGO_YAW))
    road.planview.set_start_point(100 - 1.75 * right[0] - 50 * along[0], 200 - 1.75 * right[1] - 50 * along[1],
                                  EGO_YAW)
    odr = xodr.OpenDrive("road")
    odr.add_road(road)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "road.xodr"))
    (drive,) = read_osi(_gt_trace(tmp_path / "on_map.osi", map_reference="maps/road.xodr"))
    assert drive.map_id.startswith("xodr-") and drive.lanes.height == 3
    db = tmp_path / "osi.duckdb"
    assert ingest("osi", [tmp_path / "on_map.osi"], db).drives == 1
    with duckdb.connect(str(db), read_only=True) as con:
        lanes = con.sql("select distinct lane_id from track_lanes where actor_id = '1' and dist_m = 0").fetchall()
    assert lanes == [("-1_1",)]


def test_an_mcap_trace_reads_like_the_osi_file(tmp_path):
    writer_module = pytest.importorskip("mcap_protobuf.writer")
    path = tmp_path / "run.mcap"
    with open(path, "wb") as f:
        writer = writer_module.Writer(f)
        for i in range(STEPS):
            gt = _ground_truth(i)
            t_ns = gt.timestamp.seconds * 1_000_000_000 + gt.timestamp.nanos
            writer.write_message(topic="ground_truth", message=gt, log_time=t_ns, publish_time=t_ns)
        writer.finish()
    (drive,) = read_osi(path)
    (want,) = read_osi(_gt_trace(tmp_path / "ref.osi"))
    assert drive.drive_id == "run" and drive.tracks.drop("drive_id").equals(want.tracks.drop("drive_id"))
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match=r"run.mcap: not a readable MCAP file"):
        list(read_osi(path))
