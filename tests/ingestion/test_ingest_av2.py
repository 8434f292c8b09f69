"""The AV2 reader on the bundled Argoverse 2 fixtures (tests/data/av2): four sensor logs, one forecasting scenario.

Facts measured on these files (the tests assert them):
- every annotation timestamp has an ego pose with exactly the same stamp, so the ego has one row per stamp;
- moving REGULAR_VEHICLE rows (speed > 1 m/s) that lie inside a lane polygon with |heading difference| < 30 deg:
  65.0 % (3b3570b4, Miami: 28 % of those rows lie more than 3 m outside the cropped map archive), 89.9 %, 91.8 %,
  77.4 %; 79.6 % pooled. With the ego rotation transposed (a wrong transform) these fall to 1.6-5.6 %. The ego is inside an aligned lane
  at every sample of all five drives.
- junctions per map: 3 (forecasting), 6, 10, 14, 6; the same for any join tolerance from 0 to 1 m.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest

from logiq_sql import ingest
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.ingest import expand
from logiq_sql.ingestion.readers.av2 import (
    ATTRIBUTION,
    EGO_CENTRE_AHEAD_M,
    FORECASTING_KINDS,
    SENSOR_KINDS,
    log_folders,
    read_av2,
)

DATA = Path(__file__).parents[1] / "data" / "av2"
SENSOR = sorted(p.name for p in (DATA / "sensor").iterdir())
SCENARIO = "0a1e6f0a-1817-4a98-b02e-db8c9327d151"
ALL = sorted([*SENSOR, SCENARIO])
JUNCTIONS = {SCENARIO: 3, "3b3570b4-7b0b-3268-a571-b0889dbf40b6": 6, "3bffdcff-c3a7-38b6-a0f2-64196d130958": 10,
             "7fab2350-7eaf-3b7e-a39d-6937a4c1bede": 14, "adcf7d18-0510-35b0-a2fa-b4cea13a6d76": 6}
SMALL_LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def annotations(log: str) -> pl.DataFrame:
    return pl.read_ipc(next((DATA / "sensor" / log).glob("annotations*.feather")))


def archive(drive: str) -> dict:
    return json.loads(next((DATA).glob(f"*/{drive}/**/log_map_archive_*.json")).read_text())


@pytest.fixture(scope="module")
def con(tmp_path_factory, ingested):
    db = ingested(tmp_path_factory.mktemp("av2") / "av2.duckdb", "av2", [DATA])  # ingested once per session
    summary = ingested.summary("av2", [DATA])
    assert (summary.drives, summary.rejected, summary.rows_rejected) == (5, 0, 0)
    with duckdb.connect(str(db), read_only=True) as c:
        yield c


def q(con, sql: str, **params) -> pl.DataFrame:
    return con.sql(sql, params=params or None).pl()


# ------------------------------------------------------------------------------------------------ drives, ego

def test_expand_finds_every_log_folder_sorted():
    folders = expand("av2", [DATA])
    assert [f.name for f in folders] == [SCENARIO, *SENSOR]  # motion_forecasting/ sorts before sensor/
    one = DATA / "sensor" / SMALL_LOG
    assert expand("av2", [one]) == [one]
    assert log_folders(one / "city_SE3_egovehicle.feather") == [one]


def test_five_drives_with_one_ego_each(con):
    drives = q(con, "select * from drive_inputs order by drive_id")
    assert drives["drive_id"].to_list() == ALL
    assert set(drives["status"]) == {"ingested"}
    assert set(drives["source_format"]) == {"av2"}
    assert drives["map_id"].to_list() == ALL
    assert set(drives["dt_s"]) == {0.1}
    assert set(drives["attribution"]) == {ATTRIBUTION}
    assert drives.filter(pl.col("drive_id") == SCENARIO)["ego_actor_id"].to_list() == ["AV"]
    assert set(drives.filter(pl.col("drive_id") != SCENARIO)["ego_actor_id"]) == {"ego"}
    egos = q(con, "select drive_id, count(distinct actor_id) as n, min(actor_id) as actor, min(kind) as kind, "
                  "min(length_m) as length, min(width_m) as width from tracks where is_ego group by 1 order by 1")
    assert egos["n"].to_list() == [1] * 5
    assert set(egos["kind"]) == {"vehicle"}
    assert set(egos["length"]) == {4.877} and set(egos["width"]) == {2.0}  # the EGO_VEHICLE box of AV2
    assert (egos.join(drives, on="drive_id").filter(pl.col("actor") != pl.col("ego_actor_id"))).is_empty()


@pytest.mark.parametrize("log", SENSOR)
def test_ego_has_one_row_per_annotation_timestamp(con, log):
    stamps = annotations(log)["timestamp_ns"].unique().sort().to_numpy()
    ego = q(con, "select frame, t_s from tracks where drive_id = $d and is_ego order by frame", d=log)
    assert ego.height == stamps.size
    assert np.allclose(ego["t_s"].to_numpy(), (stamps - stamps[0]) / 1e9)
    assert ego["frame"].to_list() == list(range(stamps.size))  # the ~10 Hz stamps land on consecutive frames


def test_forecasting_av_is_the_ego_and_every_row_is_kept(con):
    raw = pl.read_parquet(next((DATA / "motion_forecasting" / SCENARIO).glob("scenario_*.parquet")))
    tracks = q(con, "select * from tracks where drive_id = $d", d=SCENARIO)
    assert tracks.height == raw.height  # observed=False (the 6 s future) is recorded data too
    av = tracks.filter(pl.col("is_ego"))
    assert set(av["actor_id"]) == {"AV"} and av.height == 110
    # speed is the velocity projected on the heading; the centre is moved ahead of the pose origin
    r = raw.filter((pl.col("track_id") == "AV") & (pl.col("timestep") == 20)).row(0, named=True)
    t = av.filter(pl.col("frame") == 20).row(0, named=True)
    h = r["heading"]
    assert t["speed_mps"] == pytest.approx(r["velocity_x"] * math.cos(h) + r["velocity_y"] * math.sin(h))
    assert t["x_m"] == pytest.approx(r["position_x"] + EGO_CENTRE_AHEAD_M * math.cos(h))
    assert t["y_m"] == pytest.approx(r["position_y"] + EGO_CENTRE_AHEAD_M * math.sin(h))
    assert t["t_s"] == pytest.approx(2.0)


# ----------------------------------------------------------------------------------------------- transform

def _qmul(a: tuple, b: tuple) -> tuple:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def _rotate(qu: tuple, v: tuple) -> tuple:
    """q v q* with the Hamilton product: independent of the reader's rotation matrices."""
    n = math.sqrt(sum(c * c for c in qu))
    qu = tuple(c / n for c in qu)
    conj = (qu[0], -qu[1], -qu[2], -qu[3])
    return _qmul(_qmul(qu, (0.0, *v)), conj)[1:]


def _yaw(qu: tuple) -> float:
    w, x, y, z = qu
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@pytest.mark.parametrize("log", SENSOR)
def test_city_frame_transform_against_quaternion_algebra(con, log):
    ann = annotations(log).filter(pl.col("category") == "REGULAR_VEHICLE")
    poses = pl.read_ipc(DATA / "sensor" / log / "city_SE3_egovehicle.feather")
    stamps = ann["timestamp_ns"].unique().sort()
    picks = ann.filter(pl.col("timestamp_ns").is_in([stamps[0], stamps[len(stamps) // 2], stamps[-1]]))
    picks = picks.sort("timestamp_ns", "track_uuid").gather_every(7)  # a handful of rows at three times
    assert picks.height >= 3
    for row in picks.join(poses, on="timestamp_ns", suffix="_ego").iter_rows(named=True):  # the exact pose
        q_ego = (row["qw_ego"], row["qx_ego"], row["qy_ego"], row["qz_ego"])
        q_obj = (row["qw"], row["qx"], row["qy"], row["qz"])
        rx, ry, _ = _rotate(q_ego, (row["tx_m"], row["ty_m"], row["tz_m"]))
        x, y = rx + row["tx_m_ego"], ry + row["ty_m_ego"]
        yaw = _yaw(_qmul(q_ego, q_obj))
        got = q(con, "select x_m, y_m, heading_rad from tracks t join drive_inputs using (drive_id) "
                     "where drive_id = $d and actor_id = $a and abs(t_s - ($ts - $t0) / 1e9) < 1e-6",
                d=log, a=row["track_uuid"], ts=row["timestamp_ns"], t0=stamps[0]).row(0, named=True)
        assert got["x_m"] == pytest.approx(x, abs=1e-6) and got["y_m"] == pytest.approx(y, abs=1e-6)
        assert math.remainder(got["heading_rad"] - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    # the ego: its box centre EGO_CENTRE_AHEAD_M ahead of the pose origin, along the pose's forward axis
    row = poses.filter(pl.col("timestamp_ns") == stamps[len(stamps) // 2]).row(0, named=True)
    q_ego = (row["qw"], row["qx"], row["qy"], row["qz"])
    fx, fy, _ = _rotate(q_ego, (EGO_CENTRE_AHEAD_M, 0.0, 0.0))
    got = q(con, "select x_m, y_m, heading_rad from tracks where drive_id = $d and is_ego "
                 "and abs(t_s - $t) < 1e-6", d=log, t=(row["timestamp_ns"] - stamps[0]) / 1e9).row(0, named=True)
    assert (got["x_m"], got["y_m"]) == pytest.approx((row["tx_m"] + fx, row["ty_m"] + fy), abs=1e-6)
    assert math.remainder(got["heading_rad"] - _yaw(q_ego), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_moving_cars_localise_onto_lanes_in_their_direction(con):
    """Fails if the ego-to-city transform is wrong (transposed rotation: 1.6-5.6 % instead of 65-92 %)."""
    cats = pl.concat([annotations(log).select("track_uuid", "category").unique().with_columns(drive_id=pl.lit(log))
                      for log in SENSOR])
    con.register("_cats", cats)
    share = q(con, """
        select t.drive_id, count(*) as n,
            count(*) filter (where exists (
                select 1 from track_lanes l where l.drive_id = t.drive_id and l.actor_id = t.actor_id
                and l.frame = t.frame and l.dist_m = 0 and abs(l.heading_diff_rad) < radians(30))) as aligned
        from tracks t join _cats c on c.drive_id = t.drive_id and c.track_uuid = t.actor_id
        where c.category = 'REGULAR_VEHICLE' and t.speed_mps > 1
        group by 1 order by 1""")
    con.unregister("_cats")
    ratio = (share["aligned"] / share["n"]).round(3).to_list()
    assert ratio == [0.650, 0.899, 0.918, 0.774]
    assert share["aligned"].sum() / share["n"].sum() > 0.75  # 79.6 %
    ego = q(con, """
        select count(*) as n, count(*) filter (where exists (
                select 1 from track_lanes l where l.drive_id = t.drive_id and l.actor_id = t.actor_id
                and l.frame = t.frame and l.dist_m = 0 and abs(l.heading_diff_rad) < radians(30))) as aligned
        from tracks t where is_ego""").row(0)
    assert ego == (735, 735)  # 157 + 3 * 156 sensor samples + 110 forecasting steps


# ---------------------------------------------------------------------------------------------------- kinds

def test_kind_mapping(con):
    cats = pl.concat([annotations(log).select("track_uuid", "category").unique().with_columns(drive_id=pl.lit(log))
                      for log in SENSOR])
    con.register("_cats", cats)
    kinds = dict(q(con, "select distinct c.category, t.kind from tracks t join _cats c "
                        "on c.drive_id = t.drive_id and c.track_uuid = t.actor_id").iter_rows())
    con.unregister("_cats")
    assert kinds == {
        "REGULAR_VEHICLE": "vehicle", "LARGE_VEHICLE": "vehicle", "BOX_TRUCK": "truck", "TRUCK": "truck",
        "TRUCK_CAB": "truck", "VEHICULAR_TRAILER": "trailer", "BUS": "bus", "MOTORCYCLE": "motorcycle",
        "BICYCLE": "object", "WHEELED_DEVICE": "object", "BOLLARD": "object", "CONSTRUCTION_CONE": "object",
        "PEDESTRIAN": "person", "STROLLER": "person", "SIGN": "sign",
    }  # EGO_VEHICLE is not an actor: the ego comes from the pose file
    raw = pl.read_parquet(next((DATA / "motion_forecasting" / SCENARIO).glob("scenario_*.parquet")))
    types = raw.filter(pl.col("track_id") != "AV").select("track_id", "object_type").unique()
    got = dict(q(con, "select actor_id, kind from tracks where drive_id = $d", d=SCENARIO).unique().iter_rows())
    assert {t: got[a] for a, t in types.iter_rows()} == {
        "vehicle": "vehicle", "pedestrian": "person", "riderless_bicycle": "object", "static": "object",
        "background": "object"}
    assert set(SENSOR_KINDS.values()) | set(FORECASTING_KINDS.values()) <= {
        "object", "person", "cyclist", "vehicle", "truck", "trailer", "animal", "sign", "bus", "motorcycle"}


# ------------------------------------------------------------------------------------------------------ map

def test_lanes_neighbours_successors_lights(con):
    lanes = q(con, "select * from lanes")
    assert lanes.group_by("map_id").len().sort("map_id")["len"].to_list() == [
        len(archive(d)["lane_segments"]) for d in sorted(ALL)]
    assert set(lanes["lane_type"]) == {"VEHICLE", "BIKE", "BUS"}
    assert lanes["speed_limit_mps"].null_count() == lanes.height
    # AV2 right neighbours drive the same way; some left neighbours are across the centre line
    right = lanes.filter(pl.col("right_lane_id").is_not_null())["right_same_direction"]
    left = lanes.filter(pl.col("left_lane_id").is_not_null())["left_same_direction"]
    assert right.all() and left.sum() < left.len()
    succ = q(con, "select * from lane_successors")
    assert succ["turn"].null_count() == succ.height
    assert q(con, "select count(*) as n from lane_successors s anti join lanes l "
                  "on l.map_id = s.map_id and l.lane_id = s.successor_id")["n"][0] == 0
    assert q(con, "select count(*) as n from traffic_lights")["n"][0] == 0


def test_junctions_cover_every_intersection_lane(con):
    counts = dict(q(con, "select map_id, count(*) from junctions group by 1").iter_rows())
    assert counts == JUNCTIONS
    lanes = q(con, "select map_id, lane_id, junction_id from lanes")
    for drive in ALL:
        inter = {k for k, v in archive(drive)["lane_segments"].items() if v["is_intersection"]}
        mine = lanes.filter(pl.col("map_id") == drive)
        assert set(mine.filter(pl.col("junction_id").is_not_null())["lane_id"]) == inter
    orphans = q(con, "select count(*) as n from lanes l anti join junctions j using (map_id, junction_id) "
                     "where l.junction_id is not null")
    assert orphans["n"][0] == 0


# ---------------------------------------------------------------------------------------------------- errors

def _copy_log(tmp_path: Path, log: str = SMALL_LOG) -> Path:
    folder = tmp_path / log
    shutil.copytree(DATA / "sensor" / log, folder)
    return folder


def test_missing_pose_file_is_a_clear_error(tmp_path):
    folder = _copy_log(tmp_path)
    (folder / "city_SE3_egovehicle.feather").unlink()
    with pytest.raises(InputError) as err:
        list(read_av2(folder))
    pose = folder / "city_SE3_egovehicle.feather"
    assert str(err.value) == (
        f"{pose}: missing: the ego poses are needed to place the ego-frame boxes in the city frame. "
        "Fix: copy the log's city_SE3_egovehicle.feather from the AV2 sensor dataset beside annotations.feather.")
    # through ingest: the log is a rejected drive named after its folder, with that reason
    summary = ingest("av2", [tmp_path], tmp_path / "x.duckdb")
    assert (summary.drives, summary.rejected) == (0, 1)
    with duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True) as c:
        row = c.execute("select drive_id, status, reject_reason from drive_inputs").fetchall()
    assert row == [(SMALL_LOG, "rejected", str(err.value))]


def test_missing_map_and_broken_feather(tmp_path):
    folder = _copy_log(tmp_path)
    shutil.rmtree(folder / "map")
    with pytest.raises(InputError, match=r"no map archive \(map/log_map_archive_\*\.json"):
        list(read_av2(folder))
    folder = _copy_log(tmp_path / "b")
    ann = folder / "annotations.feather"
    ann.write_bytes(ann.read_bytes()[:2000])
    with pytest.raises(InputError) as err:
        list(read_av2(folder))
    assert str(err.value).startswith(f"{ann}: not a readable AV2 annotation file (")
    assert str(err.value).endswith("Fix: copy the file again from the Argoverse 2 dataset; it must be complete.")


def test_unknown_category_ridden_bicycle_and_double_frame_are_counted(tmp_path):
    folder = _copy_log(tmp_path)
    ann = pl.read_ipc(folder / "annotations.feather")
    t0 = ann["timestamp_ns"].min()
    bike = ann.filter(pl.col("category") == "BICYCLE").row(0, named=True)
    car = ann.filter(pl.col("category") == "REGULAR_VEHICLE").row(0, named=True)
    extra = pl.DataFrame([
        {**car, "track_uuid": "hover", "category": "HOVERBOARD"},  # not in the table: dropped, counted
        {**bike, "track_uuid": "rider", "category": "BICYCLIST", "tx_m": bike["tx_m"] + 0.3},  # rides the bike
        {**car, "timestamp_ns": car["timestamp_ns"] + 20_000_000},  # 20 ms later: the same frame again
    ], schema=ann.schema)
    pl.concat([ann, extra]).write_ipc(folder / "annotations.feather")
    (drive,) = read_av2(folder)
    # the stray stamp 20 ms after the first sweep also gets an ego sample, which falls into the ego's frame 0 too
    stamps = ann["timestamp_ns"].n_unique() + 1
    assert drive.rows_read == ann.height + 3 + stamps
    assert drive.rows_rejected == 4
    assert drive.reject_reason == (
        "1 row(s) of unmapped AV2 categor(y/ies) dropped: HOVERBOARD (1); add them to the kind table of "
        "logiq_sql/ingestion/readers/av2.py (annotations.feather); "
        "1 BICYCLE row(s) within 1 m of a BICYCLIST dropped (one road user: the rider is the actor); "
        "2 row(s) falling in a frame their actor already has dropped (the row nearer to frame * 0.1 s kept)")
    tracks = drive.tracks
    assert tracks.filter(pl.col("actor_id") == "rider")["kind"].to_list() == ["cyclist"]
    assert tracks.filter((pl.col("actor_id") == bike["track_uuid"])
                         & (pl.col("t_s") == (bike["timestamp_ns"] - t0) / 1e9)).is_empty()
    for actor in (car["track_uuid"], "ego"):
        kept = tracks.filter((pl.col("actor_id") == actor) & (pl.col("frame") == 0))
        assert kept["t_s"].to_list() == [(car["timestamp_ns"] - t0) / 1e9]  # the on-time row wins
