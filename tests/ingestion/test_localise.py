"""Lane localisation (``logiq_sql.ingestion.localise``, a compiled look-up) against the shapely computation it replaced
(``benchmarks/shapely_lanes.py``: GEOS's STRtree, contains, distance, line_locate_point), and against a slow, obvious
search with shapely: the same (row, lane) pairs, distances and heading differences within 1e-9 on every bundled
map, on hand-made lanes with points on vertices, edges, holes and lane ends, and on random lanes."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.shapely_lanes import ShapelyLanes
from logiq_sql.ingestion import localise
from logiq_sql.ingestion.localise import LaneIndex, locate
from logiq_sql.ingestion.readers.av2 import read_av2
from logiq_sql.ingestion.readers.commonroad import read_commonroad
from logiq_sql.ingestion.readers.scenarionet import read_scenarionet
from logiq_sql.ingestion.readers.sumo import read_sumo

DATA = Path(__file__).parents[1] / "data"
SCENE = DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0061.pkl"


def differences(lanes: pl.DataFrame, x: np.ndarray, y: np.ndarray, heading: np.ndarray) -> tuple[int, pl.DataFrame]:
    """(pairs shapely finds, the pairs that differ: missing on one side, or off by more than 1e-9)."""
    pairs = {}
    for name, found in (("ref", ShapelyLanes(lanes).locate(x, y, heading)), ("new", LaneIndex(lanes).locate(x, y, heading))):
        row, lane, dist, diff = found
        pairs[name] = pl.DataFrame({"row": row, "lane": lane, f"dist_{name}": dist, f"diff_{name}": diff},
                                   schema_overrides={"row": pl.Int64, "lane": pl.Int64})
    both = pairs["ref"].join(pairs["new"], on=["row", "lane"], how="full", coalesce=True)
    turn = (pl.col("diff_ref") - pl.col("diff_new")).abs()
    return pairs["ref"].height, both.filter(
        pl.col("dist_ref").is_null() | pl.col("dist_new").is_null()
        | ((pl.col("dist_ref") - pl.col("dist_new")).abs() > 1e-9)
        | (pl.min_horizontal(turn, 2 * np.pi - turn) > 1e-9))  # +-pi is one heading


def bundled_maps():
    """One drive of every bundled map: NGSIM and its traffic-light scenarios, nuScenes, Argoverse 2, SUMO."""
    drives = {}
    for path in sorted((DATA / "commonroad_ngsim").rglob("*.xml*")):
        for drive in read_commonroad(path):
            drives.setdefault(drive.map_id, drive)
    for path in sorted((DATA / "nuscenes_mini_scenarionet").glob("*.pkl")):
        drives.setdefault(*(lambda d: (d.map_id, d))(read_scenarionet(path)[0]))
    for path in sorted([*(DATA / "av2/motion_forecasting").iterdir(), *(DATA / "av2/sensor").iterdir()]):
        drive = next(read_av2(path))
        drives.setdefault(drive.map_id, drive)
    for run in ("motorway_s1", "junction_s1"):
        drive = next(read_sumo(DATA / "sumo" / run))
        drives.setdefault(drive.map_id, drive)
    return list(drives.values())


def test_the_look_up_gives_shapelys_pairs_on_every_bundled_map():
    drives = bundled_maps()
    assert len(drives) > 100
    total, rng = 0, np.random.default_rng(11)
    for drive in drives:
        tracks = drive.tracks.with_columns(pl.col("heading_rad").fill_null(0.0))
        if tracks.height > 30_000:  # the SUMO runs: every 4th frame keeps the test short
            tracks = tracks.filter(pl.col("frame") % 4 == 0)
        x, y = tracks["x_m"].to_numpy(), tracks["y_m"].to_numpy()
        # the rows as recorded, and as many again moved off them (normal, 2.5 m): between lanes, off the map
        x = np.r_[x, x + rng.normal(0, 2.5, len(x))]
        y = np.r_[y, y + rng.normal(0, 2.5, len(y))]
        heading = np.r_[tracks["heading_rad"].to_numpy(), rng.uniform(-np.pi, np.pi, len(tracks))]
        rows, differ = differences(drive.lanes, x, y, heading)
        assert differ.is_empty(), (drive.map_id, differ)
        total += rows
    assert total > 1_000_000


EDGE_CASES = pl.DataFrame({
    "lane_id": ["notched", "holed", "bowtie", "straight", "flat", "repeated", "dot", "nested"],
    "polygon_wkt": [
        "POLYGON ((0 0, 10 0, 10 10, 6 10, 6 4, 4 4, 4 10, 0 10, 0 0))",
        "POLYGON ((20 0, 30 0, 30 10, 20 10, 20 0), (23 3, 27 3, 27 7, 23 7, 23 3))",
        "POLYGON ((40 0, 50 10, 50 0, 40 10, 40 0))",  # invalid: self-crossing
        "POLYGON ((60 0, 80 0, 80 3.5, 60 3.5, 60 0))",
        "POLYGON ((0 20, 10 20, 20 20, 0 20))",  # no area: a doubled line
        "POLYGON ((30 20, 30 20, 40 20, 40 24, 40 24, 30 24, 30 20))",  # repeated vertices
        "POLYGON ((55 22, 55 22, 55 22, 55 22))",  # a point
        "POLYGON ((60 14, 84 14, 84 30, 60 30, 60 14))",  # holds other lanes' points, and a lane end inside
    ],
    "centerline_wkt": ["LINESTRING (2 0, 2 10)", "LINESTRING (21.5 0, 21.5 10)", "LINESTRING (40 5, 50 5)",
                       "LINESTRING (60 1.75, 70 1.75, 70 1.75, 80 1.75)", "LINESTRING (0 20, 20 20)",
                       "LINESTRING (30 22, 30 22, 35 22, 40 22)", "LINESTRING (55 22, 55 22)",
                       "LINESTRING (62 16, 82 16, 82 28, 62 28, 62 16)"],  # a closed centre line: equal distances
})


def test_the_look_up_gives_shapelys_pairs_on_hand_made_edge_cases():
    vertices = shapely.get_coordinates(shapely.from_wkt(EDGE_CASES["polygon_wkt"].to_numpy()))
    lines = shapely.get_coordinates(shapely.from_wkt(EDGE_CASES["centerline_wkt"].to_numpy()))
    on_purpose = [(5, 4), (5, 7), (6, 7), (4, 10), (5, 10.5), (25, 5), (23, 5), (26.5, 6.5), (45, 5), (45, 2),
                  (45, 8), (42, 5), (48, 1), (83, 1.75), (70, 0), (70, -3), (70, 6.5), (13, 5), (-3, 0),
                  (82.5, 3.5), (33, 10), (-3 / np.sqrt(2), -3 / np.sqrt(2)), (5, 20), (5, 23), (20, 23),
                  (35, 22), (55, 22), (55, 25), (58, 22), (72, 22), (62, 22), (83, 23), (87, 22), (500, 500),
                  (np.nan, 1.0), (-1e9, 1e9)]
    rng = np.random.default_rng(3)
    edges = np.diff(vertices, axis=0) * rng.uniform(0, 1, (len(vertices) - 1, 1)) + vertices[:-1]  # on edges
    xy = np.r_[np.array(on_purpose), vertices, lines, edges, vertices + [3, 0], vertices - [0, 3],
               np.c_[rng.uniform(-4, 90, 5000), rng.uniform(-4, 34, 5000)]]
    heading = rng.uniform(-np.pi, np.pi, len(xy))
    rows, differ = differences(EDGE_CASES, xy[:, 0], xy[:, 1], heading)
    assert rows > 2500 and differ.is_empty(), differ


@st.composite
def random_lanes(draw):
    """A few lanes: star-shaped polygons (concave, some with spikes) around random centres, each with a wavy
    centre line through its centre; coordinates on a coarse lattice, so that points land on vertices and edges."""
    n = draw(st.integers(1, 4))
    polygons, lines = [], []
    for _ in range(n):
        cx, cy = draw(st.integers(0, 40)), draw(st.integers(0, 40))
        k = draw(st.integers(3, 12))
        radii = draw(st.lists(st.integers(1, 12), min_size=k, max_size=k))
        angles = np.linspace(0, 2 * np.pi, k, endpoint=False)
        ring = [(round(cx + r * np.cos(a) * 2) / 2, round(cy + r * np.sin(a) * 2) / 2) for r, a in zip(radii, angles)]
        polygons.append(shapely.Polygon(ring + ring[:1]).wkt)
        m = draw(st.integers(2, 7))
        ys = draw(st.lists(st.integers(-4, 4), min_size=m, max_size=m))
        lines.append(shapely.LineString([(cx - 10 + 20 * i / (m - 1), cy + dy / 2) for i, dy in enumerate(ys)]).wkt)
    return pl.DataFrame({"lane_id": [f"l{i}" for i in range(n)], "polygon_wkt": polygons, "centerline_wkt": lines})


@settings(max_examples=60, deadline=None)
@given(lanes=random_lanes(), seed=st.integers(0, 2**32 - 1))
def test_the_look_up_gives_shapelys_pairs_on_random_lanes(lanes, seed):
    rng = np.random.default_rng(seed)
    lattice = rng.integers(-10, 110, (400, 2)) / 2  # on the polygons' lattice: vertices, edges
    xy = np.r_[lattice, rng.uniform(-10, 55, (400, 2))]
    heading = rng.uniform(-np.pi, np.pi, len(xy))
    _, differ = differences(lanes, xy[:, 0], xy[:, 1], heading)
    assert differ.is_empty(), differ


def test_lane_index_matches_a_brute_force_search():
    (drive,) = read_scenarionet(SCENE)
    index = LaneIndex(drive.lanes)
    rng = np.random.default_rng(7)
    ego = drive.tracks.filter(pl.col("is_ego"))
    x = ego["x_m"].to_numpy()[::5] + rng.normal(0, 2, size=ego.height)[::5]
    y = ego["y_m"].to_numpy()[::5] + rng.normal(0, 2, size=ego.height)[::5]
    heading = rng.uniform(-np.pi, np.pi, size=x.size)
    row, lane, dist, diff = index.locate(x, y, heading)
    polygons = shapely.from_wkt(drive.lanes["polygon_wkt"].to_numpy())
    lines = shapely.from_wkt(drive.lanes["centerline_wkt"].to_numpy())
    for i in range(x.size):  # every lane within 3 m, found by checking every lane
        p = shapely.Point(x[i], y[i])
        expected = {j for j in range(len(polygons)) if polygons[j].distance(p) <= 3.0}
        assert set(lane[row == i]) == expected
    assert len(row) > 50
    for k in range(len(row)):
        p = shapely.Point(x[row[k]], y[row[k]])
        coords = np.asarray(lines[lane[k]].coords)
        segs = [shapely.LineString(coords[m:m + 2]) for m in range(len(coords) - 1)]
        d = np.array([seg.distance(p) for seg in segs])
        nearest = np.flatnonzero(d <= d.min() + 1e-9)  # two segments tie where the point projects on a vertex
        lane_heading = heading[row[k]] - diff[k]
        gaps = [lane_heading - np.arctan2(*(coords[m + 1] - coords[m])[::-1]) for m in nearest]
        assert any(abs(np.arctan2(np.sin(g), np.cos(g))) < 1e-6 for g in gaps)
        assert dist[k] == polygons[lane[k]].distance(p)


def test_static_objects_are_not_localised():
    (drive,) = read_scenarionet(SCENE)
    tracks = drive.tracks.with_columns(pl.col("heading_rad").fill_null(0.0))
    found = locate(tracks, drive.lanes)
    kinds = tracks.select("actor_id", "kind").unique()
    assert set(found.join(kinds, on="actor_id")["kind"]) == {"vehicle", "truck", "bus", "person", "motorcycle"}


@pytest.mark.parametrize("chunk", [500, 7])
def test_chunks_threads_a_pickled_index_and_a_full_buffer_give_one_calls_rows(monkeypatch, chunk):
    """The index is plain arrays: shared by threads, sent pickled (as to Spark executors); chunks of any size, and
    an output buffer too small for one point's lanes, give what one call gives."""
    (drive,) = read_scenarionet(SCENE)
    tracks = drive.tracks.with_columns(pl.col("heading_rad").fill_null(0.0))
    if chunk < 500:
        tracks = tracks.head(3000)
    one_call = locate(tracks, drive.lanes)
    monkeypatch.setattr(localise, "CHUNK_POINTS", chunk)
    monkeypatch.setattr(localise, "WORKERS", 3)
    chunked = locate(tracks, drive.lanes, pickle.loads(pickle.dumps(LaneIndex(drive.lanes))))
    key = ["drive_id", "actor_id", "frame", "lane_id"]
    assert chunked.sort(key).equals(one_call.sort(key)) and one_call.height > 0


def test_the_look_up_runs_from_a_zipped_package_with_nowhere_to_cache(tmp_path):
    """As on a Spark executor given the package as a .zip and no writable home: compiled afresh, same pairs."""
    import os
    import subprocess
    import sys
    import zipfile

    package = Path(localise.__file__).parents[1]
    with zipfile.ZipFile(tmp_path / "logiq_sql.zip", "w") as z:
        for f in package.rglob("*.py"):
            z.write(f, f.relative_to(package.parent))
    script = ("import numpy as np, polars as pl\nfrom logiq_sql.ingestion import localise\n"
              "lanes = pl.DataFrame({'lane_id': ['a'], 'polygon_wkt': ['POLYGON ((0 0, 10 0, 10 3, 0 3, 0 0))'],"
              " 'centerline_wkt': ['LINESTRING (0 1.5, 10 1.5)']})\n"
              "row, lane, dist, diff = localise.LaneIndex(lanes).locate(np.array([1.0, 12.0]), np.array([1.0, 1.0]),"
              " np.array([0.5, 0.0]))\nprint(localise.__file__, localise._CACHE, row.tolist(), dist.tolist(), diff.tolist())")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA")}
    env.update(PYTHONPATH=str(tmp_path / "logiq_sql.zip"), HOME="/proc")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(tmp_path / "logiq_sql.zip/logiq_sql/ingestion/localise.py"), "False", "[0,", "1]",
                                  "[0.0,", "2.0]", "[0.5,", "0.0]"]
