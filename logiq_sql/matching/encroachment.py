"""Encroachment areas: where an actor's path through a junction crosses the ego's (shapely, vectorised).

The one geometric step of junction matching that is not SQL (like localisation at ingest). It reads the
``crossing_pairs`` and ``passages`` tables and the tracks, and writes ``encroachments``:

    path            the centre line of an actor's positions from its junction entry to its exit, swept by
                    half its box width on each side (flat ends): the area its box covers inside the junction.
                    Its vertices are the mean positions of the rows over each PATH_STEP_M (0.5 m) of s_m, so a
                    car that waits with a jittering position is one point, not a knot of zig-zags, then smoothed
                    over SMOOTH_M (1 m) of s_m either side, so a car passing at speed (one row per stretch) does
                    not carry its position jitter into a band wider than its path
    area            ego path ∩ actor path (the "shared area where its path intersects the Ego's path inside
                    the junction"); pairs whose paths do not overlap get no row
    *_occupancy_    the stretch of each actor's own path (actor_paths.s_m of its box centre) along which its box
    from/to_s_m     overlaps the area: the box (length x width, the passage's median size) is placed at every
                    vertex of the centre line, headed as the rows of that stretch, and tested against the area;
                    the least and greatest s_m of the vertices whose box touches it. A rigid box on a curve is
                    not its swept band: on a left turn the band's inner edge runs ahead of the box's front
                    corner, and where the ego crosses the first oncoming lane at a shallow angle that put the
                    band's edge 2-3 m along the path before the box (a left-turner waiting clear of the lane
                    counted as already in it). Resolution: the 0.5 m of the vertices. When no vertex's box
                    touches the area (a sliver), the projection of the area's vertices on the centre line,
                    widened by half the box length, stands in.
"""

from __future__ import annotations

import numpy as np
import polars as pl
import shapely

from logiq_sql.core.schema import DEFAULT_SIZE_M
from logiq_sql.engines import as_engine

ENCROACHMENTS_SCHEMA = {
    "drive_id": pl.String, "ego_id": pl.String, "ego_passage": pl.Int64, "actor_id": pl.String,
    "actor_passage": pl.Int64, "junction_id": pl.String, "area_m2": pl.Float64, "area_wkt": pl.String,
    "ego_occupancy_from_s_m": pl.Float64, "ego_occupancy_to_s_m": pl.Float64,
    "actor_occupancy_from_s_m": pl.Float64, "actor_occupancy_to_s_m": pl.Float64,
}
# the tables encroachments() reads and the columns it reads of each (None: every one), every table keyed by
# drive_id and joined on the integer keys (drive_key, actor_key); a drive without crossing pairs has no rows. Spark
# ships only these columns to its Python workers
ENCROACHMENT_READS = {
    "crossing_pairs": None,
    "passages": ("drive_id", "actor_id", "passage", "entry_frame", "exit_frame", "drive_key", "actor_key"),
    "actor_paths": ("drive_id", "frame", "s_m", "drive_key", "actor_key"),
    "tracks": ("drive_id", "frame", "x_m", "y_m", "heading_rad", "length_m", "width_m", "drive_key", "actor_key"),
}
MIN_AREA_M2 = 0.01  # paths that only touch share no area
PATH_STEP_M = 0.5  # a path's vertices: the mean position of its rows over each 0.5 m of s_m
SMOOTH_M = 1.0  # then the mean of the vertices within 1 m of s_m either side
CAR_LENGTH_M, CAR_WIDTH_M = DEFAULT_SIZE_M["vehicle"]  # a passage whose rows have no size: a car's box


def _smoothed(coords: pl.DataFrame) -> pl.DataFrame:
    """Each vertex's position and heading the mean of the vertices of its line within SMOOTH_M of s_m on either
    side: a fast actor has one row per stretch, so its line would carry every jitter of its positions, and a
    buffered zig-zag is wider than the path. Vectorised: cumulative sums over the lines sorted by (k, piece)."""
    key = coords["k"].to_numpy() * 10**9 + coords["piece"].to_numpy().astype(np.int64)
    reach = int(round(SMOOTH_M / PATH_STEP_M))
    lo, hi = np.searchsorted(key, key - reach, "left"), np.searchsorted(key, key + reach, "right")
    out = {}
    for col in ("x_m", "y_m", "sin", "cos"):
        total = np.concatenate([[0.0], np.cumsum(coords[col].to_numpy())])
        out[col] = (total[hi] - total[lo]) / (hi - lo)
    return coords.with_columns(**{c: pl.Series(v) for c, v in out.items()})


def _paths(engine) -> tuple[pl.DataFrame, np.ndarray, np.ndarray, pl.DataFrame]:
    """Every passage named by a crossing pair: its key, its centre line, its swept path, and its vertices with
    their distance along the line (``along``, shifted so that it grows across all lines) and their s_m."""
    points = engine.frame("""
        with wanted as (
            select drive_key, ego_key as actor_key, ego_passage as passage from crossing_pairs
            union
            select drive_key, actor_key, actor_passage as passage from crossing_pairs
        )
        select p.drive_id, p.actor_id, p.passage, a.s_m, t.x_m, t.y_m, t.heading_rad, t.length_m, t.width_m
        from passages as p
        inner join wanted as w
            on p.drive_key = w.drive_key and p.actor_key = w.actor_key and p.passage = w.passage
        inner join tracks as t
            on p.drive_key = t.drive_key and p.actor_key = t.actor_key
            and t.frame between p.entry_frame and p.exit_frame
        inner join actor_paths as a
            on t.drive_key = a.drive_key and t.actor_key = a.actor_key and t.frame = a.frame
        order by p.drive_id, p.actor_id, p.passage, t.frame
    """)
    passage_key = pl.struct("drive_id", "actor_id", "passage").rank("dense").cast(pl.Int64) - 1
    keyed = points.with_columns(passage_key.alias("k"))
    paths = (keyed.group_by("k", maintain_order=True)
             .agg(pl.first("drive_id"), pl.first("actor_id"), pl.first("passage"),
                  pl.col("length_m").median().fill_null(CAR_LENGTH_M).alias("length_m"),
                  pl.col("width_m").median().fill_null(CAR_WIDTH_M).alias("width_m"))
             .sort("k"))  # row k is line k
    # one vertex per PATH_STEP_M of s_m: the mean position of the rows in that stretch, so a car waiting with a
    # jittering position is one point where it waits, not a knot of zig-zags
    coords = (keyed.group_by("k", (pl.col("s_m") / PATH_STEP_M).floor().alias("piece"))
              .agg(pl.col("x_m").mean(), pl.col("y_m").mean(), pl.col("s_m").mean(),
                   pl.col("heading_rad").sin().mean().alias("sin"), pl.col("heading_rad").cos().mean().alias("cos"))
              .sort("k", "piece"))
    coords = _smoothed(coords).select("k", "x_m", "y_m", "s_m", pl.arctan2("sin", "cos").alias("heading_rad"))
    # a passage that stays within one stretch has no line: repeat its point so every passage has one
    single = coords.group_by("k").len().filter(pl.col("len") == 1)["k"]
    coords = pl.concat([coords, coords.filter(pl.col("k").is_in(single.implode()))]).sort("k", maintain_order=True)
    lines = shapely.linestrings(coords.select("x_m", "y_m").to_numpy(), indices=coords["k"].to_numpy())
    swept = shapely.buffer(lines, paths["width_m"].to_numpy() / 2, cap_style="flat")
    step = ((pl.col("x_m").diff().over("k") ** 2 + pl.col("y_m").diff().over("k") ** 2).sqrt()).fill_null(0.0)
    vertices = coords.with_columns(along=step.cum_sum().over("k"))
    # line k's distances start where line k-1's ended plus 1 m: one increasing scale for every line (np.interp)
    starts = vertices.group_by("k").agg((pl.max("along") + 1.0).alias("span")).sort("k").with_columns(
        start=pl.col("span").cum_sum() - pl.col("span"))
    vertices = (vertices.join(starts.select("k", "start"), on="k")
                .select("k", (pl.col("along") + pl.col("start")).alias("along"), "s_m", "start", "x_m", "y_m",
                        "heading_rad")
                .sort("along", maintain_order=True))
    return paths, lines, swept, vertices


def _extent(lines: np.ndarray, areas: np.ndarray, owners: np.ndarray, vertices: pl.DataFrame
            ) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest s_m of the vertices of each area projected onto its line (``owners``: the line's key)."""
    xy, index = shapely.get_coordinates(areas, return_index=True)
    along = shapely.line_locate_point(lines[index], shapely.points(xy))
    start = vertices.group_by("k").agg(pl.first("start")).sort("k")["start"].to_numpy()
    s = np.interp(along + start[owners[index]], vertices["along"].to_numpy(), vertices["s_m"].to_numpy())
    frame = pl.DataFrame({"owner": index, "s": s}).group_by("owner").agg(
        pl.min("s").alias("lo"), pl.max("s").alias("hi"))
    lo, hi = np.full(len(areas), np.nan), np.full(len(areas), np.nan)
    lo[frame["owner"].to_numpy()] = frame["lo"].to_numpy()
    hi[frame["owner"].to_numpy()] = frame["hi"].to_numpy()
    return lo, hi


def _occupancy(areas: np.ndarray, owners: np.ndarray, paths: pl.DataFrame, vertices: pl.DataFrame
               ) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest s_m of the vertices of each owner's line at which its box touches the area (NaN where
    none does). One box per (area, vertex of its owner's line): a vectorised intersects over them all."""
    placed = (pl.DataFrame({"area": np.arange(len(areas)), "k": owners})
              .join(vertices.select("k", "x_m", "y_m", "heading_rad", "s_m"), on="k")
              .join(paths.select("k", "length_m", "width_m"), on="k"))
    half_length = placed["length_m"].to_numpy()[:, None] / 2
    half_width = placed["width_m"].to_numpy()[:, None] / 2
    cos, sin = np.cos(placed["heading_rad"].to_numpy())[:, None], np.sin(placed["heading_rad"].to_numpy())[:, None]
    along = np.array([1.0, 1.0, -1.0, -1.0]) * half_length  # the four corners: front left, front right, ...
    across = np.array([1.0, -1.0, -1.0, 1.0]) * half_width
    corners = np.stack([placed["x_m"].to_numpy()[:, None] + along * cos - across * sin,
                        placed["y_m"].to_numpy()[:, None] + along * sin + across * cos], axis=-1)
    area = placed["area"].to_numpy()
    touching = shapely.intersects(shapely.polygons(corners), areas[area])
    frame = (pl.DataFrame({"area": area, "s": placed["s_m"].to_numpy()}).filter(pl.Series(touching))
             .group_by("area").agg(pl.min("s").alias("lo"), pl.max("s").alias("hi")))
    lo, hi = np.full(len(areas), np.nan), np.full(len(areas), np.nan)
    lo[frame["area"].to_numpy()] = frame["lo"].to_numpy()
    hi[frame["area"].to_numpy()] = frame["hi"].to_numpy()
    return lo, hi


def _occupancy_of(lines, areas, owners, paths, vertices) -> tuple[np.ndarray, np.ndarray]:
    """Each area's occupancy on its owners' paths: the swept box where it touches, else the projection of the
    area on the line widened by half the box length."""
    lo, hi = _occupancy(areas, owners, paths, vertices)
    missing = np.isnan(lo)
    if missing.any():  # projected only where no box touches
        stand_in = owners[missing]
        enter, leave = _extent(lines[stand_in], areas[missing], stand_in, vertices)
        half = paths["length_m"].to_numpy()[stand_in] / 2
        lo[missing], hi[missing] = enter - half, leave + half
    return lo, hi


def encroachments(con) -> pl.DataFrame:
    """The ``encroachments`` rows of every crossing pair whose paths share an area. ``con``: a DuckDB connection
    or an engine (logiq_sql/engines/) holding the crossing_pairs, passages and actor_paths steps."""
    engine = as_engine(con)
    pairs = engine.frame("crossing_pairs")
    if pairs.is_empty():
        return pl.DataFrame(schema=ENCROACHMENTS_SCHEMA)
    paths, lines, swept, vertices = _paths(engine)
    key = paths.select("drive_id", "actor_id", "passage", "k")
    pairs = (pairs
             .join(key.rename({"actor_id": "ego_id", "passage": "ego_passage", "k": "ek"}),
                   on=["drive_id", "ego_id", "ego_passage"])
             .join(key.rename({"passage": "actor_passage", "k": "ak"}), on=["drive_id", "actor_id", "actor_passage"]))
    ek, ak = pairs["ek"].to_numpy(), pairs["ak"].to_numpy()
    areas = shapely.intersection(swept[ek], swept[ak])
    area_m2 = shapely.area(areas)
    keep = area_m2 >= MIN_AREA_M2
    pairs, ek, ak, areas, area_m2 = pairs.filter(pl.Series(keep)), ek[keep], ak[keep], areas[keep], area_m2[keep]
    ego_lo, ego_hi = _occupancy_of(lines, areas, ek, paths, vertices)
    actor_lo, actor_hi = _occupancy_of(lines, areas, ak, paths, vertices)
    return pairs.select(
        "drive_id", "ego_id", "ego_passage", "actor_id", "actor_passage", "junction_id",
        pl.Series("area_m2", area_m2), pl.Series("area_wkt", shapely.to_wkt(areas, rounding_precision=3)),
        pl.Series("ego_occupancy_from_s_m", ego_lo), pl.Series("ego_occupancy_to_s_m", ego_hi),
        pl.Series("actor_occupancy_from_s_m", actor_lo), pl.Series("actor_occupancy_to_s_m", actor_hi),
    ).cast(ENCROACHMENTS_SCHEMA)
