"""The CommonRoad reader, checked against facts read by hand from the raw XML of the NGSIM scenarios."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import polars as pl
import pytest
import shapely

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.commonroad import light_state, read_commonroad

# /work/main/tests/<this file> -> parents[2] is /work, beside the repo: /work/shared/data/real/commonroad_ngsim.
SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "commonroad_ngsim"
IN_REPO = Path(__file__).resolve().parents[1] / "data" / "commonroad_ngsim"  # the lead's copy, used if SHARED is gone
DATA = SHARED if SHARED.is_dir() else IN_REPO

US101 = "scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
PEACH = "scenarios_2020a_with_traffic_lights/USA_Peach-4_8_T-1.xml.gz"
LANKER = "scenarios_2020a_with_traffic_lights/USA_Lanker-1_3_T-1.xml.gz"


def _file(rel: str) -> Path:
    path = DATA / rel
    if not path.is_file():
        pytest.skip(f"CommonRoad NGSIM data not found ({path}); it lives in /work/shared/data/real/commonroad_ngsim")
    return path


def _one(rel: str):
    drives = read_commonroad(_file(rel))
    assert len(drives) == 1
    return drives[0]


def _check_schemas(d) -> None:
    for frame, table in ((d.tracks, schema.TRACKS), (d.lanes, schema.LANES),
                         (d.lane_successors, schema.LANE_SUCCESSORS), (d.junctions, schema.JUNCTIONS),
                         (d.traffic_lights, schema.TRAFFIC_LIGHTS),
                         (d.traffic_light_states, schema.TRAFFIC_LIGHT_STATES)):
        assert dict(frame.schema) == table.polars_schema, table.name
        for col in table.columns:
            if not col.nullable:
                assert frame[col.name].null_count() == 0, f"{table.name}.{col.name}"


# ----------------------------------------------------------------------------------------------- 2018b highway

def test_us101_2018b_drive_and_tracks():
    d = _one(US101)
    assert d.drive_id == "USA_US101-22_1_T-1@2018b"
    assert d.map_id == d.drive_id
    assert d.source_format == "commonroad"
    assert d.dt_s == pytest.approx(0.1)
    assert d.ego_actor_id is None
    assert d.attribution == "NGSIM (FHWA/US DOT public data) via CommonRoad (TUM); see SOURCE.md"
    _check_schemas(d)
    t = d.tracks
    assert t["actor_id"].n_unique() == 54  # 54 <obstacle> elements in the file
    assert t.height == d.rows_read == 5538 and d.rows_rejected == 0 and d.reject_reason is None
    assert not t["is_ego"].any()
    assert set(t["kind"]) == {"vehicle"}  # all type car
    first = t.filter(pl.col("actor_id") == "605").sort("frame").row(0, named=True)
    assert first["frame"] == 0 and first["t_s"] == 0.0
    assert (first["x_m"], first["y_m"]) == (206.0969, -156.8562)
    assert first["heading_rad"] == -0.71558
    assert first["speed_mps"] == 17.2456
    assert first["accel_mps2"] == -0.55778
    assert (first["length_m"], first["width_m"]) == (5.0292, 1.9507)
    second = t.filter((pl.col("actor_id") == "605") & (pl.col("frame") == 1)).row(0, named=True)
    assert (second["x_m"], second["y_m"], second["heading_rad"]) == (207.3966, -157.9946, -0.72235)
    assert second["t_s"] == pytest.approx(0.1)
    # one row per (actor, frame)
    assert t.unique(["actor_id", "frame"]).height == t.height


def test_us101_2018b_lanes():
    d = _one(US101)
    lane = d.lanes.filter(pl.col("lane_id") == "30").row(0, named=True)
    assert lane["right_lane_id"] == "29" and lane["right_same_direction"] is True
    assert lane["left_lane_id"] is None and lane["left_same_direction"] is None
    assert lane["junction_id"] is None and lane["lane_type"] is None
    poly = shapely.from_wkt(lane["polygon_wkt"])
    assert poly.geom_type == "Polygon" and poly.is_valid
    # leftBound starts at (-16.9525, 41.8666), rightBound at (-19.3148, 39.2846): polygon starts left, centre between
    assert lane["polygon_wkt"].startswith("POLYGON ((-16.9525 41.8666, -14.865 39.9568")
    assert lane["centerline_wkt"].startswith("LINESTRING (-18.1337 40.5756, ")
    succ = d.lane_successors.filter(pl.col("lane_id") == "30")
    assert succ["successor_id"].to_list() == ["44"] and succ["turn"].to_list() == [None]
    assert d.junctions.is_empty() and d.traffic_lights.is_empty() and d.traffic_light_states.is_empty()


def test_2018b_speed_limit_from_lanelet():
    d = _one("scenarios_2018b/USA_Peach-4_1_T-1.xml.gz")
    limits = set(d.lanes["speed_limit_mps"].drop_nulls())
    assert limits and limits <= {11.176, 13.4112, 15.6464, 3.5763}  # the <speedLimit> values of the dataset


# -------------------------------------------------------------------------------------- 2020a traffic lights

def test_peach_2020a_intersection_and_turns():
    d = _one(PEACH)
    assert d.drive_id == "USA_Peach-4_8_T-1@2020a"
    _check_schemas(d)
    # one <intersection id="43922"> (the other <intersection/> in the file is a scenario tag)
    assert d.junctions["junction_id"].to_list() == ["43922"]
    junction = shapely.from_wkt(d.junctions["polygon_wkt"][0])
    assert junction.is_valid and junction.area > 100
    lanes = {r["lane_id"]: r for r in d.lanes.to_dicts()}
    assert lanes["43590"]["junction_id"] == "43922"  # successorsLeft of incoming 43925
    assert lanes["43349"]["junction_id"] is None  # an incoming lanelet, not inside
    assert sum(r["junction_id"] == "43922" for r in lanes.values()) == 16  # 4 incomings x (1 L + 2 S + 1 R)
    assert lanes["43349"]["left_lane_id"] == "43341" and lanes["43349"]["left_same_direction"] is False
    assert lanes["43349"]["right_lane_id"] == "43208" and lanes["43349"]["right_same_direction"] is True
    assert lanes["43590"]["lane_type"] == "urban"
    assert lanes["43590"]["speed_limit_mps"] == pytest.approx(15.6464)  # via its R2-1 speed-limit sign
    turns = {(r["lane_id"], r["successor_id"]): r["turn"] for r in d.lane_successors.to_dicts()}
    assert turns[("43349", "43590")] == "left"  # incoming 43925: incomingLanelet 43349, successorsLeft 43590
    assert turns[("43208", "43592")] == "straight"
    assert turns[("43343", "43640")] == "right"
    assert sorted(v for v in turns.values() if v) == ["left"] * 4 + ["right"] * 4 + ["straight"] * 8


def test_peach_2020a_traffic_lights():
    d = _one(PEACH)
    assert sorted(d.traffic_lights["light_id"].unique()) == ["43918", "43919", "43920", "43921"]
    l18 = d.traffic_lights.filter(pl.col("light_id") == "43918").sort("lane_id")
    assert l18["lane_id"].to_list() == ["43402", "43404", "43406"]  # lanelets with trafficLightRef 43918
    assert l18.row(0, named=True)["x_m"] == pytest.approx(13.6179)
    assert l18.row(0, named=True)["y_m"] == pytest.approx(-13.3698)
    st = d.traffic_light_states
    max_frame = d.tracks["frame"].max()
    assert max_frame == 60
    assert st.height == 4 * (max_frame + 1)
    state = {(r["light_id"], r["frame"]): r["state"] for r in st.to_dicts()}
    # 43918: green 400, yellow 30, red 570 (cycle 1000), timeOffset 590: p = (k - 590) mod 1000.
    # k=19 -> p=429 (yellow, 400..429); k=20 -> p=430 (red, 430..999).
    assert state[("43918", 0)] == "yellow" and state[("43918", 19)] == "yellow"
    assert state[("43918", 20)] == "red" and state[("43918", 60)] == "red"
    # 43919: same cycle, timeOffset 1090: k=0 -> p=910 (red)
    assert state[("43919", 0)] == "red"


def test_lanker_2020a_green_and_inactive_lights():
    d = _one(LANKER)
    state = {(r["light_id"], r["frame"]): r["state"] for r in d.traffic_light_states.to_dicts()}
    # 11526: green 310, yellow 40, red 650, timeOffset 1000: p = k mod 1000 -> green over the whole drive
    assert {state[("11526", k)] for k in range(41)} == {"green"}
    # 11524: green 220, yellow 40, inactive 740, timeOffset 1360: k=0 -> p=640 -> inactive -> off
    assert state[("11524", 0)] == "off"


def test_light_state_offset_convention():
    durations, colours = [400, 30, 570], ["green", "yellow", "red"]  # light 43918 of USA_Peach-4_8_T-1
    assert light_state(durations, colours, 590, 590) == "green"  # the cycle starts at timeOffset
    assert light_state(durations, colours, 590, 989) == "green"
    assert light_state(durations, colours, 590, 990) == "yellow"
    assert light_state(durations, colours, 590, 1020) == "red"
    assert light_state(durations, colours, 590, 1590) == "green"
    assert light_state(durations, colours, 590, 589) == "red"


def test_two_2020a_files_share_a_benchmark_id_with_2018b_files():
    a = _one("scenarios_2018b/USA_Lanker-1_11_T-1.xml.gz")
    b = _one("scenarios_2020a_with_traffic_lights/USA_Lanker-complex_tl__commonroad-io_test_reading_complex_tl.xml.gz")
    assert a.drive_id == "USA_Lanker-1_11_T-1@2018b" and b.drive_id == "USA_Lanker-1_11_T-1@2020a"


def test_all_files_read():
    files = sorted(DATA.glob("*/*.xml.gz"))
    if not files:
        pytest.skip(f"CommonRoad NGSIM data not found in {DATA}")
    drives = [d for f in files for d in read_commonroad(f)]
    assert len({d.drive_id for d in drives}) == len(files)
    for d in drives:
        _check_schemas(d)
        assert d.tracks.height > 0 and d.lanes.height > 0
        assert d.rows_read == d.tracks.height + d.rows_rejected
        assert all(shapely.from_wkt(w).geom_type == "Polygon" for w in d.lanes["polygon_wkt"])
    if len(files) == 92:  # the full staged set (SOURCE.md): 5,651 time steps, 2,820 vehicle tracks
        assert sum(d.tracks.height for d in drives) == 163_350
        assert sum(d.tracks["actor_id"].n_unique() for d in drives) == 2820
        assert sum(d.tracks["frame"].max() + 1 for d in drives) == 5651


# ---------------------------------------------------------------------------------------- errors, edge cases

def test_truncated_gzip_is_an_input_error(tmp_path):
    good = gzip.compress(b'<?xml version="1.0"?><commonRoad benchmarkID="X" commonRoadVersion="2020a" '
                         b'timeStepSize="0.1">' + b"<lanelet id='1'/>" * 500 + b"</commonRoad>")
    bad = tmp_path / "cut.xml.gz"
    bad.write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError) as err:
        read_commonroad(bad)
    assert str(err.value) == (
        f"{bad}: not a readable CommonRoad XML file (Compressed file ended before the end-of-stream marker was "
        "reached). Fix: re-export or re-download the file; gzip files must be complete."
    )


def test_malformed_xml_is_an_input_error(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<commonRoad benchmarkID="X" commonRoadVersion="2020a" timeStepSize="0.1"><lanelet>')
    with pytest.raises(InputError, match=r"bad\.xml: not a readable CommonRoad XML file \(no element found"):
        read_commonroad(bad)


def test_wrong_root_is_an_input_error(tmp_path):
    bad = tmp_path / "other.xml"
    bad.write_text("<osm version='0.6'></osm>")
    with pytest.raises(InputError, match=r"other\.xml: root element is <osm>, not <commonRoad>"):
        read_commonroad(bad)


def _pt(x, y):
    return f"<point><x>{x}</x><y>{y}</y></point>"


def _state(t, x, y, yaw=0.0, v=1.0, a=None):
    acc = "" if a is None else f"<acceleration><exact>{a}</exact></acceleration>"
    return (f"<position>{_pt(x, y)}</position><orientation><exact>{yaw}</exact></orientation>"
            f"<time><exact>{t}</exact></time><velocity><exact>{v}</exact></velocity>{acc}")


SYNTHETIC = f"""<?xml version="1.0"?>
<commonRoad benchmarkID="TEST_1" commonRoadVersion="2020a" timeStepSize="0.2">
  <lanelet id="1">
    <leftBound>{_pt(0, 3)}{_pt(10, 3)}</leftBound>
    <rightBound>{_pt(0, 0)}{_pt(5, 0)}{_pt(10, 0)}</rightBound>
    <successor ref="2"/><successor ref="3"/>
    <adjacentLeft ref="4" drivingDir="opposite"/>
    <stopLine><lineMarking>solid</lineMarking><trafficLightRef ref="50"/></stopLine>
    <laneletType>urban</laneletType><laneletType>mainCarriageWay</laneletType>
  </lanelet>
  <lanelet id="2">
    <leftBound>{_pt(10, 3)}{_pt(20, 0)}</leftBound>
    <rightBound>{_pt(10, 0)}{_pt(20, 3)}</rightBound>
  </lanelet>
  <lanelet id="3">
    <leftBound>{_pt(10, 3)}{_pt(20, 13)}</leftBound>
    <rightBound>{_pt(10, 0)}{_pt(23, 10)}</rightBound>
  </lanelet>
  <lanelet id="4">
    <leftBound>{_pt(10, 6)}{_pt(0, 6)}</leftBound>
    <rightBound>{_pt(10, 3)}{_pt(0, 3)}</rightBound>
  </lanelet>
  <staticObstacle id="90"><type>parkedVehicle</type>
    <shape><rectangle><length>4</length><width>2</width></rectangle></shape>
    <initialState>{_state(0, 1, 1)}</initialState></staticObstacle>
  <dynamicObstacle id="7"><type>bicycle</type>
    <shape><rectangle><length>1.8</length><width>0.7</width></rectangle></shape>
    <initialState>{_state(0, 1, 1.5, a=0.5)}</initialState>
    <trajectory><state>{_state(1, 1.2, 1.5)}</state><state>{_state(2, "nan", 1.5)}</state>
      <state><position>{_pt(1.6, 1.5)}</position><orientation><intervalStart>0.1</intervalStart>
        <intervalEnd>0.3</intervalEnd></orientation><time><exact>3</exact></time>
        <velocity><exact>2</exact></velocity></state></trajectory></dynamicObstacle>
  <dynamicObstacle id="8"><type>unknown</type>
    <shape><circle><radius>0.5</radius></circle></shape>
    <initialState>{_state(4, 5, 5, v="inf")}</initialState></dynamicObstacle>
  <trafficLight id="50">
    <cycle><cycleElement><duration>2</duration><color>redYellow</color></cycleElement>
      <cycleElement><duration>1</duration><color>green</color></cycleElement><timeOffset>1</timeOffset></cycle>
    <active>true</active></trafficLight>
  <trafficLight id="51">
    <cycle><cycleElement><duration>5</duration><color>green</color></cycleElement></cycle>
    <active>false</active></trafficLight>
  <intersection id="60">
    <incoming id="61"><incomingLanelet ref="1"/><successorsStraight ref="2"/><successorsLeft ref="3"/></incoming>
  </intersection>
</commonRoad>
"""


def test_synthetic_plain_xml(tmp_path):
    path = tmp_path / "TEST_1.xml"
    path.write_text(SYNTHETIC)
    (d,) = read_commonroad(path)
    _check_schemas(d)
    assert d.drive_id == "TEST_1@2020a" and d.dt_s == 0.2
    t = d.tracks.sort("actor_id", "frame")
    # static obstacle 90 ignored; state 2 of 7 (x = nan) and the only state of 8 (velocity inf) rejected
    assert t["actor_id"].to_list() == ["7", "7", "7"] and t["frame"].to_list() == [0, 1, 3]
    assert d.rows_read == 5 and d.rows_rejected == 2
    assert "obstacle id(s): 7, 8" in d.reject_reason
    assert t["kind"].to_list() == ["cyclist"] * 3
    assert t["accel_mps2"].to_list() == [0.5, None, None]
    assert t["heading_rad"][2] == pytest.approx(0.2)  # interval midpoint
    assert t["t_s"].to_list() == pytest.approx([0.0, 0.2, 0.6])
    lanes = {r["lane_id"]: r for r in d.lanes.to_dicts()}
    # bounds of 2 and 3 points: both resampled to 3 points by arc length
    assert lanes["1"]["centerline_wkt"] == "LINESTRING (0 1.5, 5 1.5, 10 1.5)"
    assert lanes["1"]["lane_type"] == "urban"
    assert lanes["1"]["left_lane_id"] == "4" and lanes["1"]["left_same_direction"] is False
    assert lanes["1"]["right_lane_id"] is None
    # lanelet 2 has crossing bounds (a bow tie): repaired to its largest valid part
    bow = shapely.from_wkt(lanes["2"]["polygon_wkt"])
    assert bow.geom_type == "Polygon" and bow.is_valid and bow.area == pytest.approx(7.5)
    assert lanes["2"]["junction_id"] == "60" and lanes["3"]["junction_id"] == "60"
    assert lanes["1"]["junction_id"] is None and lanes["4"]["junction_id"] is None
    turns = {r["successor_id"]: r["turn"] for r in d.lane_successors.to_dicts()}
    assert turns == {"2": "straight", "3": "left"}
    junction = shapely.from_wkt(d.junctions["polygon_wkt"][0])
    expected = shapely.union_all([bow, shapely.from_wkt(lanes["3"]["polygon_wkt"])])
    assert d.junctions["junction_id"].to_list() == ["60"]
    assert junction.symmetric_difference(expected).area < 1e-3  # WKT keeps 4 decimals
    assert d.traffic_lights.select("light_id", "lane_id").rows() == [("50", "1")]
    assert d.traffic_lights["x_m"].to_list() == [None]
    states = {(r["light_id"], r["frame"]): r["state"] for r in d.traffic_light_states.to_dicts()}
    # 50: redYellow 2, green 1, offset 1: k=0 -> p=2 green; k=1 -> 0 red_yellow; k=2 -> 1; k=3 -> 2 green
    assert [states[("50", k)] for k in range(4)] == ["green", "red_yellow", "red_yellow", "green"]
    assert {states[("51", k)] for k in range(4)} == {"off"}  # <active>false</active>
    assert max(k for _, k in states) == 3  # frames 0..max track frame


def test_gzipped_and_plain_read_the_same(tmp_path):
    plain = tmp_path / "a.xml"
    plain.write_text(SYNTHETIC)
    gz = tmp_path / "a.xml.gz"
    gz.write_bytes(gzip.compress(SYNTHETIC.encode()))
    (p,), (g,) = read_commonroad(plain), read_commonroad(gz)
    assert p.tracks.equals(g.tracks) and p.lanes.equals(g.lanes)
    assert not math.isnan(p.tracks["x_m"].sum())
