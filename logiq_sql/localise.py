"""Map localisation: which lanes each track row lies in or near, vectorised with shapely 2 and numpy.

For every track row of a moving kind (static kinds such as cones are skipped), every lane polygon within
``LOCALISATION_RANGE_M`` (3 m) of the box centre is kept with its distance (0 inside) and the heading difference
to the lane direction: the direction of the centre-line segment nearest to the point. Scenarios then pick lanes
with their own ``lane_calculation_tolerance_length`` in SQL (``queries/relations/actor_lanes.sql``).
"""

from __future__ import annotations

import numpy as np
import polars as pl
import shapely

from logiq_sql import schema

STATIC_KINDS = ("object", "fod", "sign")
CHUNK_POINTS = 250_000  # bounds the memory of one shapely query


class LaneIndex:
    """The lanes of one map: prepared polygons and the centre-line vertices for direction look-ups."""

    def __init__(self, lanes: pl.DataFrame):
        self.lane_ids = lanes["lane_id"].to_numpy()
        self.polygons = shapely.from_wkt(lanes["polygon_wkt"].to_numpy())
        self.lines = shapely.from_wkt(lanes["centerline_wkt"].to_numpy())
        shapely.prepare(self.polygons)  # prepared polygons make the within-distance and inside tests fast
        coords, owner = shapely.get_coordinates(self.lines, return_index=True)
        cum = np.cumsum(np.r_[0.0, np.hypot(*np.diff(coords, axis=0).T)])
        starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
        arc = cum - np.repeat(cum[starts], np.diff(np.r_[starts, len(coords)]))  # restarts on each line
        self.span = float(arc.max() if len(arc) else 0.0) + 1.0
        self.key = arc + owner * self.span  # sorted: lane by lane, arc length within
        self.coords, self.owner = coords, owner
        self.first = np.full(len(self.lines), -1)
        self.last = np.full(len(self.lines), -1)
        self.first[owner[starts]] = starts
        self.last[owner[np.r_[starts[1:] - 1, len(coords) - 1]]] = np.r_[starts[1:] - 1, len(coords) - 1]

    def direction(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Heading of the centre-line segment of ``lane`` that contains arc length ``s``."""
        i = np.searchsorted(self.key, s + lane * self.span, side="right") - 1
        i = np.clip(i, self.first[lane], np.maximum(self.last[lane] - 1, self.first[lane]))
        j = np.minimum(i + 1, self.last[lane])
        d = self.coords[j] - self.coords[i]
        return np.arctan2(d[:, 1], d[:, 0])

    def locate(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray):
        """(row index, lane index, distance to polygon, heading minus lane direction) for every pair in range."""
        points = shapely.points(x, y)
        # the tree holds the points and the (prepared) polygons query it: faster than the other way round
        lane, row = shapely.STRtree(points).query(self.polygons, predicate="dwithin",
                                                  distance=schema.LOCALISATION_RANGE_M)
        inside = shapely.contains_xy(self.polygons[lane], x[row], y[row])
        dist = np.zeros(len(row))
        dist[~inside] = shapely.distance(self.polygons[lane[~inside]], points[row[~inside]])
        s = shapely.line_locate_point(self.lines[lane], points[row])
        lane_heading = self.direction(lane, s)
        diff = np.arctan2(np.sin(heading[row] - lane_heading), np.cos(heading[row] - lane_heading))
        return row, lane, dist, diff


def locate(tracks: pl.DataFrame, lanes: pl.DataFrame, index: LaneIndex | None = None) -> pl.DataFrame:
    """Rows of ``track_lanes`` for ``tracks`` (drives on one map) against ``lanes`` (that map)."""
    moving = tracks.filter(~pl.col("kind").is_in(STATIC_KINDS)) if "kind" in tracks.columns else tracks
    if moving.is_empty() or lanes.is_empty():
        return schema.empty(schema.TRACK_LANES)
    index = index or LaneIndex(lanes)
    parts = []
    for start in range(0, moving.height, CHUNK_POINTS):
        chunk = moving.slice(start, CHUNK_POINTS)
        row, lane, dist, diff = index.locate(chunk["x_m"].to_numpy(), chunk["y_m"].to_numpy(),
                                             chunk["heading_rad"].to_numpy())
        parts.append(pl.DataFrame({
            "drive_id": chunk["drive_id"].to_numpy()[row], "actor_id": chunk["actor_id"].to_numpy()[row],
            "frame": chunk["frame"].to_numpy()[row], "lane_id": index.lane_ids[lane], "dist_m": dist,
            "heading_diff_rad": diff,
        }, schema=schema.TRACK_LANES.polars_schema))
    return pl.concat(parts) if parts else schema.empty(schema.TRACK_LANES)
