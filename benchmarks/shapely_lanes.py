"""The shapely lane look-up ingest used until issue 33 (GEOS's STRtree query, prepared contains, distance,
line_locate_point), kept as it was: the oracle of ``tests/ingestion/test_localise.py`` and the old side of
``benchmarks/lane_lookup.py``."""

from __future__ import annotations

import threading

import numpy as np
import polars as pl
import shapely

from logiq_sql.core import schema
from logiq_sql.ingestion.localise import STATIC_KINDS, arc_length_keys


class _Geometry:
    """One thread's lanes: polygons and their reach prepared (fast point-in-polygon tests), the grown boxes in an
    STRtree, the centre lines."""

    def __init__(self, wkb: dict[str, np.ndarray]):
        self.polygons = shapely.from_wkb(wkb["polygons"])
        self.reach = shapely.from_wkb(wkb["reach"])
        self.boxes = shapely.STRtree(shapely.from_wkb(wkb["boxes"]))
        self.lines = shapely.from_wkb(wkb["lines"])
        shapely.prepare(self.polygons)
        shapely.prepare(self.reach)


class ShapelyLanes:
    """The lanes of one map: their geometries (each thread prepares its own) and the centre-line vertices for
    direction look-ups."""

    def __init__(self, lanes: pl.DataFrame):
        self.lane_ids = lanes["lane_id"]
        polygons = shapely.from_wkt(lanes["polygon_wkt"].to_numpy())
        lines = shapely.from_wkt(lanes["centerline_wkt"].to_numpy())
        r = schema.LOCALISATION_RANGE_M
        b = shapely.bounds(polygons)
        boxes = shapely.box(b[:, 0] - r, b[:, 1] - r, b[:, 2] + r, b[:, 3] + r)
        # every point within r of a lane lies inside its buffer by r + 0.1 m: the buffer's arcs are chords that
        # stay within cos(pi / 32) (0.5 %) of the radius, so this is an exact pre-filter for the distance test;
        # an invalid polygon (possible in canonical Parquet) may buffer to less than itself: its box is used
        reach = np.where(shapely.is_valid(polygons), shapely.buffer(polygons, r + 0.1), boxes)
        # the geometries as WKB, from which each thread makes its own (_Geometry)
        self.wkb = {name: shapely.to_wkb(g) for name, g in
                    (("polygons", polygons), ("reach", reach), ("boxes", boxes), ("lines", lines))}
        self.local = threading.local()
        self.coords, self.owner, self.span, self.key, self.first, self.last = arc_length_keys(lines)

    def direction(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Heading of the centre-line segment of ``lane`` that contains arc length ``s``."""
        i = np.searchsorted(self.key, s + lane * self.span, side="right") - 1
        i = np.clip(i, self.first[lane], np.maximum(self.last[lane] - 1, self.first[lane]))
        j = np.minimum(i + 1, self.last[lane])
        d = self.coords[j] - self.coords[i]
        return np.arctan2(d[:, 1], d[:, 0])

    def geometry(self) -> _Geometry:
        """This thread's own copies of the lanes."""
        mine = getattr(self.local, "geometry", None)
        if mine is None:
            mine = self.local.geometry = _Geometry(self.wkb)
        return mine

    def locate(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray):
        """(row index, lane index, distance to polygon, heading minus lane direction) for every pair in range."""
        g = self.geometry()
        points = shapely.points(x, y)
        row, lane = g.boxes.query(points)  # the point lies in the lane's box grown by the range
        reach = shapely.contains_xy(g.reach[lane], x[row], y[row])
        row, lane = row[reach], lane[reach]
        inside = shapely.contains_xy(g.polygons[lane], x[row], y[row])
        dist = np.zeros(len(row))
        dist[~inside] = shapely.distance(g.polygons[lane[~inside]], points[row[~inside]])
        near = dist <= schema.LOCALISATION_RANGE_M
        row, lane, dist = row[near], lane[near], dist[near]
        s = shapely.line_locate_point(g.lines[lane], points[row])
        lane_heading = self.direction(lane, s)
        diff = np.arctan2(np.sin(heading[row] - lane_heading), np.cos(heading[row] - lane_heading))
        return row, lane, dist, diff


def shapely_locate(tracks: pl.DataFrame, lanes: pl.DataFrame) -> pl.DataFrame:
    """Rows of ``track_lanes`` for ``tracks`` (drives on one map) against ``lanes`` (that map), as ingest stored
    them with this look-up (one thread)."""
    moving = tracks.filter(~pl.col("kind").is_in(STATIC_KINDS)) if "kind" in tracks.columns else tracks
    if moving.is_empty() or lanes.is_empty():
        return schema.empty(schema.TRACK_LANES)
    index = ShapelyLanes(lanes)
    row, lane, dist, diff = index.locate(moving["x_m"].to_numpy(), moving["y_m"].to_numpy(),
                                         moving["heading_rad"].to_numpy())
    return moving.select(pl.col("drive_id", "actor_id", "frame").gather(row)).with_columns(
        lane_id=index.lane_ids.gather(lane), dist_m=pl.Series(dist), heading_diff_rad=pl.Series(diff),
    ).cast(schema.TRACK_LANES.polars_schema)
