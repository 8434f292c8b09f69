"""Lane localisation against a slow, obvious computation with shapely, on the real nuScenes map of scene-0061."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import shapely

from logiq_sql.localise import LaneIndex, locate
from logiq_sql.readers.scenarionet import read_scenarionet

SCENE = Path(__file__).parent / "data/nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0061.pkl"


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


def test_every_thread_queries_its_own_lane_geometries(monkeypatch):
    """GEOS prepared geometries build caches on first use and are not safe to share between threads: each worker
    gets its own copies, and localising in many small chunks on threads gives what one sequential call gives."""
    import threading

    from logiq_sql import localise

    (drive,) = read_scenarionet(SCENE)
    tracks = drive.tracks.with_columns(pl.col("heading_rad").fill_null(0.0))
    index = LaneIndex(drive.lanes)
    one_call = locate(tracks, drive.lanes, index)
    seen: dict[int, object] = {}
    original = LaneIndex.geometry

    def recorded(self):
        g = original(self)
        seen.setdefault(threading.get_ident(), g)
        assert seen[threading.get_ident()] is g  # a thread keeps its own copies
        return g

    monkeypatch.setattr(LaneIndex, "geometry", recorded)
    monkeypatch.setattr(localise, "CHUNK_POINTS", 500)
    monkeypatch.setattr(localise, "WORKERS", 3)
    chunked = locate(tracks, drive.lanes, LaneIndex(drive.lanes))
    assert len(seen) > 1 and len({id(g) for g in seen.values()}) == len(seen)
    key = ["drive_id", "actor_id", "frame", "lane_id"]
    assert chunked.sort(key).equals(one_call.sort(key)) and one_call.height > 0
