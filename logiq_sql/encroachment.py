"""Encroachment areas: where an actor's path through a junction crosses the ego's (shapely, vectorised).

The one geometric step of junction matching that is not SQL (like localisation at ingest). It reads the
``crossing_pairs`` and ``passages`` tables and the tracks, and writes ``encroachments``:

    path            the centre line of an actor's positions from its junction entry to its exit, swept by
                    half its box width on each side (flat ends): the area its box covers inside the junction
    area            ego path ∩ actor path (the "shared area where its path intersects the Ego's path inside
                    the junction"); pairs whose paths do not overlap get no row
    *_enter_s_m,    the extent of the area along each actor's own path: the least and greatest position
    *_leave_s_m     (actor_paths.s_m) of the area's vertices projected onto the centre line. The box overlaps
                    the area while its centre is within half its length of that stretch (see the left-turn
                    phase query, which applies the encroachment buffers to it).
"""

from __future__ import annotations

import numpy as np
import polars as pl
import shapely

from logiq_sql.engines import as_engine

ENCROACHMENTS_SCHEMA = {
    "drive_id": pl.String, "ego_id": pl.String, "ego_passage": pl.Int64, "actor_id": pl.String,
    "actor_passage": pl.Int64, "junction_id": pl.String, "area_m2": pl.Float64, "area_wkt": pl.String,
    "ego_enter_s_m": pl.Float64, "ego_leave_s_m": pl.Float64,
    "actor_enter_s_m": pl.Float64, "actor_leave_s_m": pl.Float64,
}
# the tables encroachments() reads, every one keyed by drive_id; a drive without crossing pairs has no rows
ENCROACHMENT_READS = ("crossing_pairs", "passages", "actor_paths", "tracks")
MIN_AREA_M2 = 0.01  # paths that only touch share no area


def _paths(engine) -> tuple[pl.DataFrame, np.ndarray, np.ndarray]:
    """Every passage named by a crossing pair: its key, the path position of its first point, its centre line
    and its swept path."""
    points = engine.frame("""
        with wanted as (
            select drive_id, ego_id as actor_id, ego_passage as passage from crossing_pairs
            union
            select drive_id, actor_id, actor_passage as passage from crossing_pairs
        )
        select p.drive_id, p.actor_id, p.passage, a.s_m, t.x_m, t.y_m, t.width_m
        from passages as p
        inner join wanted as w
            on p.drive_id = w.drive_id and p.actor_id = w.actor_id and p.passage = w.passage
        inner join tracks as t
            on p.drive_id = t.drive_id and p.actor_id = t.actor_id and t.frame between p.entry_frame and p.exit_frame
        inner join actor_paths as a
            on t.drive_id = a.drive_id and t.actor_id = a.actor_id and t.frame = a.frame
        order by p.drive_id, p.actor_id, p.passage, t.frame
    """)
    passage_key = pl.struct("drive_id", "actor_id", "passage").rank("dense").cast(pl.Int64) - 1
    keyed = points.with_columns(passage_key.alias("k"))
    paths = (keyed.group_by("k", maintain_order=True)
             .agg(pl.first("drive_id"), pl.first("actor_id"), pl.first("passage"), pl.first("s_m").alias("first_s_m"),
                  pl.col("width_m").median().alias("width_m"), pl.len().alias("n")))
    # a passage seen at one frame has no line: repeat its point so every passage has one
    single = paths.filter(pl.col("n") == 1)["k"]
    coords = keyed.select("k", "x_m", "y_m")
    coords = pl.concat([coords, coords.filter(pl.col("k").is_in(single.implode()))]).sort("k", maintain_order=True)
    lines = shapely.linestrings(coords.select("x_m", "y_m").to_numpy(), indices=coords["k"].to_numpy())
    swept = shapely.buffer(lines, paths["width_m"].fill_null(1.8).to_numpy() / 2, cap_style="flat")
    return paths.drop("n"), lines, swept


def _extent(lines: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least and greatest position along each line of the vertices of its area, projected onto the line."""
    xy, owner = shapely.get_coordinates(areas, return_index=True)
    s = shapely.line_locate_point(lines[owner], shapely.points(xy))
    frame = pl.DataFrame({"owner": owner, "s": s}).group_by("owner").agg(
        pl.min("s").alias("lo"), pl.max("s").alias("hi"))
    lo, hi = np.full(len(areas), np.nan), np.full(len(areas), np.nan)
    lo[frame["owner"].to_numpy()] = frame["lo"].to_numpy()
    hi[frame["owner"].to_numpy()] = frame["hi"].to_numpy()
    return lo, hi


def encroachments(con) -> pl.DataFrame:
    """The ``encroachments`` rows of every crossing pair whose paths share an area. ``con``: a DuckDB connection
    or an engine (logiq_sql/engines.py) holding the crossing_pairs, passages and actor_paths steps."""
    engine = as_engine(con)
    pairs = engine.frame("crossing_pairs")
    if pairs.is_empty():
        return pl.DataFrame(schema=ENCROACHMENTS_SCHEMA)
    paths, lines, swept = _paths(engine)
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
    entry_s = paths["first_s_m"].to_numpy()  # s_m of each line's first point: positions along it add to it
    ego_lo, ego_hi = _extent(lines[ek], areas)
    actor_lo, actor_hi = _extent(lines[ak], areas)
    return pairs.select(
        "drive_id", "ego_id", "ego_passage", "actor_id", "actor_passage", "junction_id",
        pl.Series("area_m2", area_m2), pl.Series("area_wkt", shapely.to_wkt(areas, rounding_precision=3)),
        pl.Series("ego_enter_s_m", entry_s[ek] + ego_lo), pl.Series("ego_leave_s_m", entry_s[ek] + ego_hi),
        pl.Series("actor_enter_s_m", entry_s[ak] + actor_lo), pl.Series("actor_leave_s_m", entry_s[ak] + actor_hi),
    ).cast(ENCROACHMENTS_SCHEMA)
