"""OpenDRIVE maps in (issue 20): converted with netconvert, checked against the same map read as a SUMO network.

Maps are made in the test: the bundled junction network converted to OpenDRIVE by netconvert itself, and a
straight road written with ``scenariogeneration`` away from the origin (x 1000, y 500: netconvert would move it to
0, 0 without the offset handling).
"""

from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest
import shapely

from logiq_sql import ingest
from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.opendrive import read_opendrive, xodr_map
from logiq_sql.ingestion.readers.sumo import read_sumo

pytestmark = pytest.mark.sumo
JUNCTION = Path(__file__).parents[1] / "data" / "sumo" / "junction_s1"


@pytest.fixture(scope="module")
def sumo_drive():
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    return next(read_sumo(JUNCTION))


@pytest.fixture(scope="module")
def junction_xodr(tmp_path_factory, sumo_drive) -> Path:
    """The junction run's network as OpenDRIVE, written by netconvert."""
    from logiq_sql.ingestion.readers.sumo import sumo_bin

    out = tmp_path_factory.mktemp("xodr") / "junction.xodr"
    bin_dir = sumo_bin()
    subprocess.run([str(bin_dir / "netconvert"), "--sumo-net-file", str(JUNCTION / "network.net.xml.gz"),
                    "--opendrive-output", str(out)], check=True, capture_output=True,
                   env={**os.environ, "SUMO_HOME": str(bin_dir.parent)})
    return out


def _lines(lanes: pl.DataFrame) -> np.ndarray:
    return shapely.from_wkt(lanes["centerline_wkt"].to_numpy())


def _correspondence(sumo: pl.DataFrame, xodr: pl.DataFrame) -> tuple[dict[str, str], np.ndarray]:
    """Each SUMO lane -> the OpenDRIVE lane nearest to it (Hausdorff distance of the centre lines), and that
    distance per SUMO lane."""
    a, b = _lines(sumo), _lines(xodr)
    dist = np.array([[shapely.hausdorff_distance(x, y) for y in b] for x in a])
    nearest = dist.argmin(axis=1)
    return dict(zip(sumo["lane_id"], xodr["lane_id"].to_numpy()[nearest], strict=True)), dist.min(axis=1)


def test_the_junction_as_opendrive_gives_the_same_lanes_successors_and_junction(sumo_drive, junction_xodr):
    map_id, (lanes, successors, junctions, lights) = xodr_map(junction_xodr)
    assert map_id.startswith("xodr-")
    want = sumo_drive
    assert (lanes.height, successors.height, junctions.height) == (
        want.lanes.height, want.lane_successors.height, want.junctions.height) == (40, 36, 1)
    same, dist = _correspondence(want.lanes, lanes)
    assert len(set(same.values())) == len(same)  # one to one
    internal = want.lanes["lane_type"].to_numpy() == "internal"
    # measured: 0.0 on the normal lanes; 0.62 m at most on the junction's curved lanes (netconvert fits the
    # OpenDRIVE connecting roads with other curves than its own internal lanes)
    assert dist[~internal].max() < 0.05, dist[~internal].max()
    assert dist[internal].max() < 1.0, dist[internal].max()
    # the same neighbours and the same lane graph with the same turns, through the correspondence
    mapped = want.lanes.with_columns(pl.col(c).replace(same) for c in ("lane_id", "left_lane_id", "right_lane_id"))
    cols = ["lane_id", "left_lane_id", "left_same_direction", "right_lane_id", "right_same_direction"]
    assert mapped.select(cols).sort("lane_id").equals(lanes.select(cols).sort("lane_id"))
    edges = want.lane_successors.with_columns(pl.col(c).replace(same) for c in ("lane_id", "successor_id"))
    key = ["lane_id", "successor_id", "turn"]
    assert edges.select(key).sort(key).equals(successors.select(key).sort(key))
    # junction lanes lie in the junction, whose area is the same
    assert lanes.filter(pl.col("lane_type") == "internal")["junction_id"].to_list() == ["1"] * int(internal.sum())
    a, b = shapely.from_wkt(want.junctions["polygon_wkt"][0]), shapely.from_wkt(junctions["polygon_wkt"][0])
    assert a.intersection(b).area / a.union(b).area > 0.99
    assert lights.height == want.traffic_lights.height == 32


def test_tracks_beside_the_map_land_on_the_same_lanes(tmp_path, sumo_drive, junction_xodr):
    """The run's first 40 s of tracks, ingested once on the SUMO map (canonical Parquet) and once beside the
    OpenDRIVE map: every row finds the corresponding lanes."""
    tracks = sumo_drive.tracks.filter(pl.col("t_s") <= 40.0)
    on_sumo, on_xodr = tmp_path / "sumo_map", tmp_path / "xodr_map"
    for folder in (on_sumo, on_xodr):
        folder.mkdir()
        tracks.write_parquet(folder / "tracks.parquet")
    for table in schema.MAP_TABLES:
        getattr(sumo_drive, table.name).write_parquet(on_sumo / f"{table.name}.parquet")
    pl.DataFrame({"drive_id": [sumo_drive.drive_id], "map_id": [sumo_drive.map_id]}).write_parquet(
        on_sumo / "drives.parquet")
    (on_xodr / "map.xodr").write_bytes(junction_xodr.read_bytes())
    sumo_db, xodr_db = tmp_path / "sumo.duckdb", tmp_path / "xodr.duckdb"
    assert ingest("parquet", [on_sumo], sumo_db).drives == 1
    summary = ingest("opendrive", [tmp_path / "xodr_map"], xodr_db)  # a folder: its .xodr found
    assert (summary.drives, summary.rejected) == (1, 0)
    same, _ = _correspondence(sumo_drive.lanes, xodr_map(junction_xodr)[1][0])
    query = "select actor_id, frame, lane_id from track_lanes where dist_m = 0 order by all"
    with duckdb.connect(str(sumo_db), read_only=True) as con:
        want = con.sql(query).pl().with_columns(pl.col("lane_id").replace(same))
    with duckdb.connect(str(xodr_db), read_only=True) as con:
        got = con.sql(query).pl()
        source = con.sql("select source_format, map_id from drive_inputs").fetchall()
    assert source == [("opendrive", xodr_map(junction_xodr)[0])]
    assert want.height > 4000
    agree = want.join(got, on=["actor_id", "frame", "lane_id"], how="semi").height / want.height
    print(f"rows on a lane: {want.height}, agreeing: {agree:.4f}")
    assert agree > 0.99, agree


def test_a_scenariogeneration_road_keeps_the_map_frame(tmp_path):
    """A straight road starting at (1000, 500), heading 0.3 rad, 2 lanes of 3.5 m each way: lane centres lie at
    1.75 m and 5.25 m either side of the reference line, in the file's coordinates."""
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    xodr = pytest.importorskip("scenariogeneration.xodr")
    road = xodr.create_road(xodr.Line(200), id=1, left_lanes=2, right_lanes=2, lane_width=3.5)
    road.planview.set_start_point(1000, 500, 0.3)
    odr = xodr.OpenDrive("straight")
    odr.add_road(road)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "straight.xodr"))
    _, (lanes, successors, junctions, _) = xodr_map(tmp_path / "straight.xodr")
    heading = 0.3
    right = np.array([math.sin(heading), -math.cos(heading)])  # unit vector to the right of the road
    along = np.array([math.cos(heading), math.sin(heading)])
    start = np.array([1000.0, 500.0])
    got = {r["lane_id"]: shapely.get_coordinates(shapely.from_wkt(r["centerline_wkt"]))
           for r in lanes.iter_rows(named=True)}
    assert set(got) == {"-1_0", "-1_1", "1_0", "1_1"}  # no U-turn lanes: the map has none
    for lane_id, offset_m, forward in (("-1_1", 1.75, True), ("-1_0", 5.25, True), ("1_1", -1.75, False),
                                       ("1_0", -5.25, False)):
        ends = [start + offset_m * right, start + 200 * along + offset_m * right]
        expected = np.array(ends if forward else ends[::-1])
        assert np.abs(got[lane_id] - expected).max() < 0.02, (lane_id, got[lane_id], expected)
    left = {r["lane_id"]: (r["left_lane_id"], r["left_same_direction"]) for r in lanes.iter_rows(named=True)}
    assert left["-1_1"] == ("1_1", False) and left["-1_0"] == ("-1_1", True)
    assert successors.is_empty() and junctions.is_empty()


def test_a_broken_map_is_rejected_naming_the_file(tmp_path):
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / "map.xodr").write_text("<OpenDRIVE><header revMajor='1' revMinor='4'/><road id='1' length='x'>")
    pl.DataFrame({"drive_id": ["d"], "actor_id": ["a"], "kind": ["vehicle"], "t_s": [0.0], "x_m": [0.0],
                  "y_m": [0.0]}).write_parquet(folder / "tracks.parquet")
    with pytest.raises(InputError, match=r"map.xodr: netconvert could not convert the OpenDRIVE map"):
        list(read_opendrive(folder))
    db = tmp_path / "x.duckdb"
    assert ingest("opendrive", [folder], db).rejected == 1
    with duckdb.connect(str(db), read_only=True) as con:
        ((status, reason),) = con.sql("select status, reject_reason from drive_inputs").fetchall()
        assert con.sql("select count(*) from tracks").fetchall() == [(0,)]
    assert status == "rejected" and str(folder / "map.xodr") in reason


def test_a_scenariogeneration_junction_gives_every_movement_with_its_turn(tmp_path):
    """Four roads (one lane of 3 m each way) meeting at a junction of radius 15 m, every pair connected: each
    incoming lane ends 15 m from the junction centre, 1.5 m right of its road's axis, and reaches the three other
    roads through junction lanes, turning right, straight and left."""
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    xodr = pytest.importorskip("scenariogeneration.xodr")
    roads = [xodr.create_road(xodr.Line(100), id=i, left_lanes=1, right_lanes=1, lane_width=3.0)
             for i in (1, 2, 3, 4)]
    creator = xodr.CommonJunctionCreator(id=100, name="cross", startnum=100)
    for road, angle in zip(roads, (0, np.pi / 2, np.pi, 3 * np.pi / 2), strict=True):
        creator.add_incoming_road_circular_geometry(road=road, radius=15, angle=angle, road_connection="successor")
    for a, b in ((1, 2), (1, 3), (1, 4), (2, 3), (2, 4), (3, 4)):
        creator.add_connection(road_one_id=a, road_two_id=b)
    odr = xodr.OpenDrive("cross")
    for road in roads:
        odr.add_road(road)
    odr.add_junction_creator(creator)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(tmp_path / "cross.xodr"))
    _, (lanes, successors, junctions, _) = xodr_map(tmp_path / "cross.xodr")
    assert junctions["junction_id"].to_list() == ["100"]
    centre = shapely.from_wkt(junctions["polygon_wkt"][0]).centroid
    incoming = lanes.filter((pl.col("lane_type") == "normal") & pl.col("lane_id").str.starts_with("-"))
    assert incoming.height == 4
    headings = []
    for line in _lines(incoming):
        xy = shapely.get_coordinates(line)
        assert math.hypot(*(xy[-1] - [centre.x, centre.y])) == pytest.approx(math.hypot(15.0, 1.5), abs=0.01)
        headings.append(round(math.degrees(math.atan2(*(xy[-1] - xy[-2])[::-1]))))
    assert sorted(headings) == [-90, 0, 90, 180]
    inside = set(lanes.filter(pl.col("junction_id") == "100")["lane_id"])
    assert inside and all(lane_id.startswith(":100_") for lane_id in inside)
    entries = successors.filter(pl.col("lane_id").is_in(incoming["lane_id"].implode()))
    assert entries["successor_id"].is_in(list(inside)).all()
    turns = entries.group_by("lane_id").agg(pl.col("turn").sort())["turn"].to_list()
    assert turns == [["left", "right", "straight"]] * 4
    # every movement reaches a lane leaving the junction (the other roads' outgoing lanes)
    graph = {}
    for a, b in successors.select("lane_id", "successor_id").iter_rows():
        graph.setdefault(a, []).append(b)

    def exits(lane_id):
        return {lane_id} if lane_id not in inside else {e for nxt in graph.get(lane_id, []) for e in exits(nxt)}

    for entry in incoming["lane_id"]:
        reached = {e for nxt in graph[entry] for e in exits(nxt)}
        assert len(reached) == 3 and not reached & set(incoming["lane_id"]), (entry, reached)


def test_two_maps_beside_one_tracks_file_are_refused(tmp_path):
    for name in ("a.xodr", "b.xodr"):
        (tmp_path / name).write_text("<OpenDRIVE/>")
    with pytest.raises(InputError, match=r"2 OpenDRIVE maps \(\*\.xodr\); a folder holds one map"):
        list(read_opendrive(tmp_path / "a.xodr"))
