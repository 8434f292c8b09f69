"""ScenarioNet reader: the restricted unpickler, the mapping rules, and facts checked on the raw nuScenes pickles."""

from __future__ import annotations

import os
import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import shapely

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.scenarionet import _kind, read_scenarionet, safe_load

DATA = Path(__file__).resolve().parents[3] / "shared/data/real/nuscenes_mini_scenarionet/original_pkl"
BUNDLED = Path(__file__).parents[1] / "data/nuscenes_mini_scenarionet"  # four of the ten scenes


def scene(name: str) -> Path:
    """The bundled copy where there is one, else the one in ../shared."""
    return BUNDLED / name if (BUNDLED / name).exists() else DATA / name


SCENE_0061 = scene("sd_nuscenes_v1.0-mini_scene-0061.pkl")
needs_data = pytest.mark.skipif(not DATA.exists(), reason=f"the ten shared nuScenes-mini scenes are not in {DATA}")

REFUSED = ("{path}: refused to load: the pickle asks for '{name}', which is not a numpy array or a plain builtin. "
           "Fix: only load ScenarioNet files you trust, converted with numpy arrays and plain containers.")
MISSING = ("{path}: missing key '{key}' in {where}. Fix: give a ScenarioNet scenario description "
           "(keys metadata, tracks, map_features; metadata id, sdc_id, sample_rate).")


# ---------------------------------------------------------------------------------------------- safety


class _Reduce:
    """Pickles as a call of ``func(*args)``: what a malicious file would contain."""

    def __init__(self, func, args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def _write(tmp_path: Path, obj, name: str = "x.pkl", protocol: int = 4) -> Path:
    path = tmp_path / name
    path.write_bytes(pickle.dumps(obj, protocol=protocol))
    return path


def test_os_system_is_refused_and_not_run(tmp_path):
    marker = tmp_path / "pwned"
    path = _write(tmp_path, {"metadata": _Reduce(os.system, ("touch " + str(marker),))})
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == REFUSED.format(path=path, name=f"{os.system.__module__}.system")
    assert not marker.exists()


@pytest.mark.parametrize("func, args", [(eval, ("1 + 1",)), (exec, ("x = 1",)), (getattr, ([], "append"))])
def test_builtin_code_execution_is_refused(tmp_path, func, args):
    path = _write(tmp_path, [_Reduce(func, args)])
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == REFUSED.format(path=path, name=f"builtins.{func.__name__}")


def test_protocol0_global_is_refused(tmp_path):
    path = tmp_path / "p0.pkl"
    path.write_bytes(b"cos\nsystem\n(S'echo hi'\ntR.")
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == REFUSED.format(path=path, name="os.system")


def test_truncated_pickle_is_an_input_error(tmp_path):
    path = tmp_path / "cut.pkl"
    path.write_bytes(SCENE_0061.read_bytes()[:5000])
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: the file is truncated or not a pickle (")
    assert msg.endswith("). Fix: copy the ScenarioNet .pkl again from its source.")


def test_text_file_is_not_a_pickle(tmp_path):
    path = tmp_path / "notes.pkl"
    path.write_text("this is not a pickle\n")
    with pytest.raises(InputError, match="is truncated or not a pickle") as err:
        read_scenarionet(path)
    assert str(err.value).startswith(f"{path}: ")


def test_empty_file_is_an_input_error(tmp_path):
    path = tmp_path / "empty.pkl"
    path.write_bytes(b"")
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == (f"{path}: the file is truncated or not a pickle (EOFError: Ran out of input). "
                              "Fix: copy the ScenarioNet .pkl again from its source.")


def test_missing_top_level_key(tmp_path):
    path = _write(tmp_path, {"metadata": {"id": "s", "sdc_id": "ego", "sample_rate": 0.1}, "map_features": {}})
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == MISSING.format(path=path, key="tracks", where="the scenario")


def test_missing_metadata_key(tmp_path):
    path = _write(tmp_path, {"metadata": {"id": "s", "sample_rate": 0.1}, "tracks": {}, "map_features": {}})
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == MISSING.format(path=path, key="sdc_id", where="metadata")


def test_missing_track_state_key(tmp_path):
    scenario = _scenario()
    del scenario["tracks"]["car"]["state"]["heading"]
    path = _write(tmp_path, scenario)
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == MISSING.format(path=path, key="heading", where="tracks['car']['state']")


def test_not_a_dict(tmp_path):
    path = _write(tmp_path, [1, 2, 3])
    with pytest.raises(InputError) as err:
        read_scenarionet(path)
    assert str(err.value) == f"{path}: the pickle holds a list, not a ScenarioNet scenario description (a dict)."


# ---------------------------------------------------------------------------------------------- rules (hand-made)


def _state(xy, heading, vel, length, width, valid=None):
    n = len(xy)
    return {
        "position": np.c_[np.asarray(xy, float), np.zeros(n)],
        "heading": np.full(n, heading, float),
        "velocity": np.asarray(vel, float).reshape(n, 2),
        "valid": np.ones(n) if valid is None else np.asarray(valid, float),
        "length": np.full((n, 1), length), "width": np.full((n, 1), width), "height": np.full((n, 1), 1.5),
    }


def _lane(x0, x1, y, polygon=True):
    line = [(x, y, 0.0) for x in np.linspace(x0, x1, int(abs(x1 - x0)) + 1)]
    line.insert(1, line[0])  # a repeated point: dropped
    f = {"type": "LANE_SURFACE_STREET", "polyline": line}
    if polygon:
        lo, hi = min(x0, x1), max(x0, x1)
        f["polygon"] = [[lo, y - 1.75], [hi, y - 1.75], [hi, y + 1.75], [lo, y + 1.75], [lo, y - 1.75]]
    else:
        f["speed_limit_kmh"] = 100
    return f


def _scenario(dataset="nuscenes"):
    """A straight road along +x: A1 -> A2 (right lane), B1 left of A1 same way, C1 right of A1 the other way."""
    xs = np.arange(5) * 1.0
    car_valid = [1, 1, 1, 0, 0]
    car_vel = [[10, 0], [10, 0], [0, 0], [0, 0], [0, 0]]
    nan_xy = np.c_[xs, np.full(5, 1.75)]
    nan_xy[1, 0] = np.nan
    return {
        "id": "toy", "version": "test", "length": 5,
        "metadata": {"id": "toy", "sdc_id": "ego", "sample_rate": 0.1, "dataset": dataset, "ts": np.arange(5) * 0.1},
        "tracks": OrderedDict(
            ego={"type": "VEHICLE", "metadata": {"type": "vehicle.car"},
                 "state": _state(np.c_[xs, np.full(5, 1.75)], 0.0, [[10, 0]] * 4 + [[0, 0]], 1.73, 4.08)},
            car={"type": "VEHICLE", "metadata": {"type": "vehicle.car"},
                 "state": _state(np.c_[xs + 20, np.full(5, 1.75)], np.pi / 2, car_vel, 4.5, 1.8, car_valid)},
            trailer={"type": "VEHICLE", "metadata": {"type": "vehicle.trailer"},
                     "state": _state(np.c_[xs, np.full(5, 5.25)], 0.0, [[0, 0]] * 5, 1.79, 2.17)},
            bad={"type": "PEDESTRIAN", "metadata": {"type": "human.pedestrian.adult"},
                 "state": _state(nan_xy, 0.0, [[1, 0]] * 5, 0.5, 0.6)},
            ghost={"type": "VEHICLE", "metadata": {"type": "vehicle.car"},
                   "state": _state(np.c_[xs, xs], 0.0, [[0, 0]] * 5, 4, 2, [0] * 5)},
        ),
        "map_features": {
            "A1": _lane(0, 50, 1.75), "A2": _lane(50.5, 100, 1.75), "B1": _lane(0, 50, 5.25),
            "C1": _lane(50, 0, -1.75), "K": _lane(100.3, 140, 1.75, polygon=False),
            "line": {"type": "ROAD_LINE_BROKEN_SINGLE_WHITE", "polyline": np.array([[0, 3.5], [50, 3.5]])},
        },
        "dynamic_map_states": {},
    }


def test_hand_made_scenario(tmp_path):
    (drive,) = read_scenarionet(_write(tmp_path, _scenario()))
    assert (drive.drive_id, drive.map_id, drive.dt_s, drive.ego_actor_id, drive.source_format) == (
        "toy", "toy", 0.1, "ego", "scenarionet")
    assert drive.attribution == "nuScenes (Motional), CC BY-NC-SA 4.0, via ScenarioNet; non-commercial; see SOURCE.md"
    t = drive.tracks
    assert t.schema == pl.Schema(schema.TRACKS.polars_schema)
    # ego 5 + car 3 valid + trailer 5 + bad 5 valid rows seen; the ghost has no valid frame
    assert drive.rows_read == 18 and drive.rows_rejected == 1 and t.height == 17
    assert drive.reject_reason == "1 row(s) with a non-finite position or heading"
    assert sorted(t.filter(pl.col("actor_id") == "bad")["frame"].to_list()) == [0, 2, 3, 4]
    ego = t.filter(pl.col("is_ego")).sort("frame")
    assert ego["actor_id"].unique().to_list() == ["ego"]
    assert ego["t_s"].to_list() == [0.0, 0.1, 0.2, 0.3, 0.4]
    assert (ego["length_m"][0], ego["width_m"][0]) == (4.08, 1.73)  # swapped
    assert ego["speed_mps"].to_list()[:4] == [10.0] * 4 and ego["speed_mps"][4] is None  # run end: derived later
    assert ego["accel_mps2"].null_count() == 5
    car = t.filter(pl.col("actor_id") == "car").sort("frame")
    assert car["frame"].to_list() == [0, 1, 2]
    # heading pi/2, velocity along +x: longitudinal speed ~0; the run's last frame (velocity 0, 0) is NULL
    assert car["speed_mps"][0] == pytest.approx(0.0, abs=1e-9) and car["speed_mps"][2] is None
    trailer = t.filter(pl.col("actor_id") == "trailer")
    assert (trailer["length_m"][0], trailer["width_m"][0], trailer["kind"][0]) == (1.79, 2.17, "trailer")  # not swapped

    lanes = {r["lane_id"]: r for r in drive.lanes.iter_rows(named=True)}
    assert drive.lanes.schema == pl.Schema(schema.LANES.polars_schema)
    assert sorted(lanes) == ["A1", "A2", "B1", "C1", "K"]  # the road line is not a lane
    a1 = lanes["A1"]
    assert (a1["left_lane_id"], a1["left_same_direction"]) == ("B1", True)
    assert (a1["right_lane_id"], a1["right_same_direction"]) == ("C1", False)
    assert (lanes["B1"]["right_lane_id"], lanes["B1"]["right_same_direction"]) == ("A1", True)
    assert lanes["B1"]["left_lane_id"] is None and lanes["A2"]["left_lane_id"] is None
    assert (lanes["C1"]["right_lane_id"], lanes["C1"]["right_same_direction"]) == ("A1", False)
    assert len(shapely.from_wkt(a1["centerline_wkt"]).coords) == 51  # duplicate point dropped, z dropped
    k_poly = shapely.from_wkt(lanes["K"]["polygon_wkt"])
    assert k_poly.geom_type == "Polygon" and k_poly.area == pytest.approx(39.7 * 3.5)  # flat-capped buffer
    assert lanes["K"]["speed_limit_mps"] is None  # nuScenes placeholder 100 km/h dropped
    assert all(r["lane_type"] == "LANE_SURFACE_STREET" and r["junction_id"] is None for r in lanes.values())
    succ = sorted(drive.lane_successors.select("lane_id", "successor_id").iter_rows())
    assert succ == [("A1", "A2"), ("A2", "K")]  # 0.5 m and 0.3 m gaps; C1 runs the other way
    assert drive.lane_successors["turn"].null_count() == 2


def test_speed_limit_and_attribution_of_other_datasets(tmp_path):
    (drive,) = read_scenarionet(_write(tmp_path, _scenario(dataset="waymo")))
    assert drive.attribution == "waymo, via ScenarioNet; see the dataset's own licence"
    k = drive.lanes.filter(pl.col("lane_id") == "K")
    assert k["speed_limit_mps"][0] == pytest.approx(100 / 3.6)


def test_graph_keys_are_used_when_present(tmp_path):
    scenario = _scenario()
    scenario["map_features"]["B1"]["exit_lanes"] = ["A2"]
    scenario["map_features"]["C1"]["entry_lanes"] = ["K"]
    scenario["map_features"]["A2"]["left_neighbor"] = [{"feature_id": "B1"}]
    (drive,) = read_scenarionet(_write(tmp_path, scenario))
    assert sorted(drive.lane_successors.select("lane_id", "successor_id").iter_rows()) == [("B1", "A2"), ("K", "C1")]
    lanes = {r["lane_id"]: r for r in drive.lanes.iter_rows(named=True)}
    assert (lanes["A2"]["left_lane_id"], lanes["A2"]["left_same_direction"]) == ("B1", True)
    assert lanes["A1"]["left_lane_id"] is None  # keys given: no geometric guess


def test_plain_containers_load(tmp_path):
    scenario = _scenario()
    scenario["extra"] = {"s": {1, 2}, "f": frozenset({3}), "c": complex(1, 2), "sl": slice(1, 2)}
    scenario["metadata"]["count"] = np.int64(5)  # a numpy scalar
    (drive,) = read_scenarionet(_write(tmp_path, scenario, protocol=3))
    assert drive.tracks.height == 17


@pytest.mark.parametrize("category, coarse, kind", [
    ("vehicle.car", "VEHICLE", "vehicle"), ("vehicle.bicycle", "CYCLIST", "cyclist"),
    ("vehicle.motorcycle", "CYCLIST", "motorcycle"), ("human.pedestrian.adult", "PEDESTRIAN", "person"),
    ("human.pedestrian.child", "PEDESTRIAN", "person"), ("human.pedestrian.police_officer", "PEDESTRIAN", "person"),
    ("human.pedestrian.construction_worker", "PEDESTRIAN", "person"),
    ("human.pedestrian.personal_mobility", "PEDESTRIAN", "person"), ("vehicle.truck", "VEHICLE", "truck"),
    ("vehicle.bus.rigid", "VEHICLE", "bus"), ("vehicle.bus.bendy", "VEHICLE", "bus"),
    ("vehicle.emergency.police", "VEHICLE", "emergency_vehicle"),
    ("vehicle.emergency.ambulance", "VEHICLE", "emergency_vehicle"), ("vehicle.trailer", "VEHICLE", "trailer"),
    ("vehicle.construction", "VEHICLE", "truck"), ("movable_object.trafficcone", "TRAFFIC_CONE", "object"),
    ("movable_object.barrier", "TRAFFIC_BARRIER", "object"), ("animal", "PEDESTRIAN", "animal"),
    ("static_object.bicycle_rack", "OBJECT", "object"), (None, "VEHICLE", "vehicle"), (None, "CYCLIST", "cyclist"),
    (None, "PEDESTRIAN", "person"), ("something.else", "TRAFFIC_CONE", "object"), (None, None, "object"),
])
def test_kinds(category, coarse, kind):
    assert _kind(coarse, category) == kind
    assert kind in schema.OBJECT_KINDS


# ---------------------------------------------------------------------------------------------- real nuScenes data

# drive_id, valid track rows, actors, LANE* features, derived successors (checked on the raw pickles)
SCENES = {
    "nuscenes_2_0.pkl": ("scene-0757", 3105, 30, 151, 176),
    "nuscenes_2_1.pkl": ("scene-0796", 3572, 52, 276, 292),
    "sd_nuscenes_v1.0-mini_scene-0061.pkl": ("scene-0061", 22611, 226, 460, 476),
    "sd_nuscenes_v1.0-mini_scene-0103.pkl": ("scene-0103", 9887, 122, 358, 383),
    "sd_nuscenes_v1.0-mini_scene-0553.pkl": ("scene-0553", 9727, 57, 421, 448),
    "sd_nuscenes_v1.0-mini_scene-0655.pkl": ("scene-0655", 11506, 141, 320, 339),
    "sd_nuscenes_v1.0-mini_scene-0916.pkl": ("scene-0916", 11855, 95, 201, 211),
    "sd_nuscenes_v1.0-mini_scene-1077.pkl": ("scene-1077", 4458, 73, 212, 228),
    "sd_nuscenes_v1.0-mini_scene-1094.pkl": ("scene-1094", 8736, 86, 288, 298),
    "sd_nuscenes_v1.0-mini_scene-1100.pkl": ("scene-1100", 4848, 33, 153, 157),
}


@needs_data
def test_all_ten_files_are_there():
    assert sorted(p.name for p in DATA.glob("*.pkl")) == sorted(SCENES)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_file_loads(name):
    if not scene(name).exists():
        pytest.skip(f"{name} is not bundled and {DATA} is absent")
    drive_id, rows, actors, n_lanes, n_succ = SCENES[name]
    (drive,) = read_scenarionet(scene(name))
    t = drive.tracks
    assert (drive.drive_id, drive.map_id, drive.ego_actor_id, drive.dt_s) == (drive_id, drive_id, "ego", 0.1)
    assert t.schema == pl.Schema(schema.TRACKS.polars_schema)
    assert drive.lanes.schema == pl.Schema(schema.LANES.polars_schema)
    assert drive.lane_successors.schema == pl.Schema(schema.LANE_SUCCESSORS.polars_schema)
    assert (t.height, drive.rows_read, drive.rows_rejected, t["actor_id"].n_unique()) == (rows, rows, 0, actors)
    assert (drive.lanes.height, drive.lane_successors.height) == (n_lanes, n_succ)
    assert set(t["kind"].unique()) <= set(schema.OBJECT_KINDS)
    assert t.filter(pl.col("is_ego"))["actor_id"].unique().to_list() == ["ego"]
    ego = t.filter(pl.col("is_ego"))
    assert (ego["length_m"] > ego["width_m"]).all()
    assert t.select(pl.struct("actor_id", "frame").is_unique().all()).item()
    assert drive.lanes["left_lane_id"].is_not_null().any() and drive.lanes["right_lane_id"].is_not_null().any()
    assert drive.junctions.is_empty() and drive.traffic_lights.is_empty() and drive.traffic_light_states.is_empty()
    polys = shapely.from_wkt(drive.lanes["polygon_wkt"].to_numpy())
    assert shapely.is_valid(polys).all() and set(shapely.get_type_id(polys)) == {3}  # all valid POLYGONs


def test_scene_0061_facts():
    (drive,) = read_scenarionet(SCENE_0061)
    t = drive.tracks
    assert drive.attribution == "nuScenes (Motional), CC BY-NC-SA 4.0, via ScenarioNet; non-commercial; see SOURCE.md"
    ego = t.filter(pl.col("is_ego")).sort("frame")
    assert ego.height == 191 and ego["frame"].to_list() == list(range(191))
    assert t["frame"].max() == 190 and t["t_s"].max() == pytest.approx(19.0)
    first = ego.row(0, named=True)
    assert (first["x_m"], first["y_m"]) == pytest.approx((411.249, 1180.743), abs=1e-3)
    assert first["heading_rad"] == pytest.approx(-1.92344, abs=1e-5)
    assert first["speed_mps"] == pytest.approx(9.1845, abs=1e-3)  # velocity (-3.167, -8.621) along the heading
    assert (first["length_m"], first["width_m"]) == (4.08, 1.73)  # raw file: length 1.73, width 4.08
    kinds = dict(t.group_by("kind").agg(pl.col("actor_id").n_unique()).iter_rows())
    # the three vehicle.bicycle tracks of scene-0061 never move more than 1 m: parked, so objects
    assert kinds == {"motorcycle": 3, "person": 60, "vehicle": 15, "truck": 7, "bus": 2, "object": 139}
    # every track with 2+ frames has its last speed NULL (the converter writes velocity 0, 0 there)
    assert t["speed_mps"].null_count() == 211

    lanes = drive.lanes
    assert lanes.height == 460 and set(lanes["lane_type"]) == {"LANE_SURFACE_STREET"}
    assert lanes["speed_limit_mps"].null_count() == 460
    succ = set(drive.lane_successors.select("lane_id", "successor_id").iter_rows())
    # along the ego's path (SSW out of scene start): connector 8f74cf95 ends where lane 79d8b56f starts,
    # (408.57, 1168.87), and 79d8b56f ends where fb2f6e0a starts, (401.38, 1149.24)
    assert ("8f74cf95-642c-4683-abd0-b7f661ba7fbd", "79d8b56f-ba80-46da-9881-d10176b250da") in succ
    assert ("79d8b56f-ba80-46da-9881-d10176b250da", "fb2f6e0a-4484-4cd2-bbef-deceac7e441f") in succ
    # the fork at (419.42, 1201.02): 91da635c and 8f74cf95 start at the same point; neither follows the other
    assert ("91da635c-b931-4517-89c9-ff90792d75f0", "8f74cf95-642c-4683-abd0-b7f661ba7fbd") not in succ
    row = {r["lane_id"]: r for r in lanes.iter_rows(named=True)}
    # 7b690728 runs beside 79d8b56f about 4 m to the west; driving SSW, east is left
    a = row["7b690728-97e7-4fe9-9116-a4a41ab39e41"]
    assert (a["left_lane_id"], a["left_same_direction"]) == ("79d8b56f-ba80-46da-9881-d10176b250da", True)
    b = row["79d8b56f-ba80-46da-9881-d10176b250da"]
    assert (b["right_lane_id"], b["right_same_direction"]) == ("7b690728-97e7-4fe9-9116-a4a41ab39e41", True)
    # Singapore drives on the left: the oncoming lane (7eaaa816, NNE) is on the right of da3704b9 (SSW)
    c = row["da3704b9-a68e-47e7-b28e-2a70dce7039f"]
    assert (c["right_lane_id"], c["right_same_direction"]) == ("7eaaa816-34ab-4400-9085-756aab7dd0eb", False)
    # 213 features carry a polygon (nuScenes lanes); 247 are bare polylines (lane connectors), buffered by 1.75 m
    raw = safe_load(SCENE_0061)["map_features"]
    lane_features = [f for f in raw.values() if f["type"].startswith("LANE")]
    assert sum("polygon" in f for f in lane_features) == 213 and len(lane_features) == 460
    connector = row["8f74cf95-642c-4683-abd0-b7f661ba7fbd"]
    assert "polygon" not in raw["8f74cf95-642c-4683-abd0-b7f661ba7fbd"]
    buffered = shapely.buffer(shapely.from_wkt(connector["centerline_wkt"]), 1.75, cap_style="flat")
    assert shapely.from_wkt(connector["polygon_wkt"]).symmetric_difference(buffered).area < 1e-3
