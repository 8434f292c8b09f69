"""Map localisation: which lanes each track row lies in or near, vectorised with shapely 2.

For every track row, every lane polygon within ``LOCALISATION_RANGE_M`` (3 m) of the box centre is kept with
its distance (0 inside) and the heading difference to the lane direction at the nearest centre-line point
(direction from the points 0.5 m before and after it). Scenarios then pick lanes with their own
``lane_calculation_tolerance_length`` in SQL (``queries/relations/actor_lanes.sql``).
"""

from __future__ import annotations

import numpy as np
import polars as pl
import shapely

from logiq_sql import schema


def locate(tracks: pl.DataFrame, lanes: pl.DataFrame) -> pl.DataFrame:
    """Rows of ``track_lanes`` for ``tracks`` (one drive) against ``lanes`` (that drive's map)."""
    if tracks.is_empty() or lanes.is_empty():
        return schema.empty(schema.TRACK_LANES)
    polygons = shapely.from_wkt(lanes["polygon_wkt"].to_numpy())
    centerlines = shapely.from_wkt(lanes["centerline_wkt"].to_numpy())
    points = shapely.points(tracks["x_m"].to_numpy(), tracks["y_m"].to_numpy())
    tree = shapely.STRtree(polygons)
    row_idx, lane_idx = tree.query(points, predicate="dwithin", distance=schema.LOCALISATION_RANGE_M)
    if len(row_idx) == 0:
        return schema.empty(schema.TRACK_LANES)
    pts = points[row_idx]
    lines = centerlines[lane_idx]
    dist = shapely.distance(polygons[lane_idx], pts)
    s = shapely.line_locate_point(lines, pts)
    before = shapely.line_interpolate_point(lines, np.maximum(s - 0.5, 0.0))
    after = shapely.line_interpolate_point(lines, s + 0.5)
    lane_heading = np.arctan2(shapely.get_y(after) - shapely.get_y(before),
                              shapely.get_x(after) - shapely.get_x(before))
    heading = tracks["heading_rad"].to_numpy()[row_idx]
    diff = np.arctan2(np.sin(heading - lane_heading), np.cos(heading - lane_heading))
    return pl.DataFrame(
        {
            "drive_id": tracks["drive_id"].to_numpy()[row_idx],
            "actor_id": tracks["actor_id"].to_numpy()[row_idx],
            "frame": tracks["frame"].to_numpy()[row_idx],
            "lane_id": lanes["lane_id"].to_numpy()[lane_idx],
            "dist_m": dist,
            "heading_diff_rad": diff,
        },
        schema=schema.TRACK_LANES.polars_schema,
    )
