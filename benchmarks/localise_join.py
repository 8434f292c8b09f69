"""Map localisation as a relational join (issue 15): EXACT BUT NOT FASTER, SO NOT WIRED IN. Ingest localised with
shapely then (``benchmarks/shapely_lanes.py``, the reference here; since issue 33 ``logiq_sql/ingestion/localise.py``
computes the same rows compiled); this module and ``benchmarks/localise_join_sql/`` are the measured alternative,
kept for a later attempt. On the base drives (1,305,714 rows, 103 maps) it gave the same
3,253,293 rows and cost about 22 CPU s against shapely's 10 (``benchmarks/README.md``, section of 2026-11-26).

Same rows as ``benchmarks.shapely_lanes.shapely_locate``: for every track row of a moving kind, every lane polygon within
``LOCALISATION_RANGE_M`` (3 m) of the box centre, its distance (0 inside) and the heading minus the direction of the
centre-line segment at ``line_locate_point`` of the point.

How: ``lane_grid`` cuts each map into square cells of ``CELL_M`` (only the cells track rows occupy, ``track_cells.sql``)
and lists, for every (cell, lane) that a point within range can fall in, the lane pieces such a point needs (numpy
and shapely, per map, not per row):

- the polygon's boundary edges (every ring) within ``min(U, range)`` of the cell, U being an upper bound of the
  distance to the boundary over the whole cell (the farthest corner from one edge): they hold the nearest edge of
  any point of the cell whose distance counts, and every edge that meets the cell; none where the cell meets no
  edge and lies inside the polygon;
- a reference point ``q`` in the cell, off the boundary, and whether the polygon contains it (``contains_xy``: the
  even-odd rule over every ring, which is also what makes an invalid polygon's answer the same);
- the centre-line segments within U_c of the cell, U_c the least over segments of the farthest corner: they hold
  the nearest segment of any point of the cell, with the arc-length keys that give its direction.

``track_lanes.sql`` joins track rows to their cell's rows (an equi-join on the cell) and does the per-row work in
SQL: a point is inside when ``q`` is and an even number of edges cross the segment from the point to ``q`` (or ``q``
is outside and the number is odd); its distance is 0 inside, else the least point-to-segment distance (GEOS's
``Distance::pointToSegment``); ``line_locate_point`` is the arc length on the nearest centre-line segment, the first
on a tie (GEOS's ``LengthIndexOfPoint``), and the direction is that of the segment whose arc-length keys (those of
``LaneIndex``, rounding included) hold it. A (cell, lane) has ``n_rows`` rows, the k-th with its k-th edge and k-th
segment; only where ``n_rows > 1`` are a row's pieces grouped.

Run ``python -m benchmarks.localise_join`` for the measurement (the base drives' Parquet of ``benchmarks.tiers``).
"""

from __future__ import annotations

import sys
import time
from itertools import pairwise
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import shapely

from benchmarks.shapely_lanes import shapely_locate as reference_locate
from logiq_sql.core import schema
from logiq_sql.ingestion.localise import LaneIndex
from logiq_sql.storage import tables

CELL_M = 1.0  # a power of two: x * (1 / CELL_M) and its floor are exact, in numpy as in SQL
SLACK_M = 1e-6  # every pruning distance is widened by this: pieces a rounding error could need are kept
SQL = Path(__file__).parent / "localise_join_sql"


def _point_segment(px, py, ax, ay, bx, by) -> np.ndarray:
    """Distance from points to segments (broadcast), for pruning only."""
    dx, dy = bx - ax, by - ay
    len2 = dx * dx + dy * dy
    with np.errstate(all="ignore"):
        t = np.clip(((px - ax) * dx + (py - ay) * dy) / len2, 0.0, 1.0)
    t = np.where(len2 > 0, t, 0.0)
    return np.hypot(px - (ax + t * dx), py - (ay + t * dy))


def _box_segment(x0, y0, c: float, ax, ay, bx, by) -> np.ndarray:
    """Distance from the boxes [x0, x0 + c] x [y0, y0 + c] to segments; 0 where they meet (Liang-Barsky)."""
    x1, y1 = x0 + c, y0 + c
    dx, dy = bx - ax, by - ay
    t0, t1 = np.zeros(np.broadcast(x0, ax).shape), np.ones(np.broadcast(x0, ax).shape)
    missed = np.zeros(t0.shape, bool)
    for p, q in ((-dx, ax - x0), (dx, x1 - ax), (-dy, ay - y0), (dy, y1 - ay)):  # p * t <= q along the segment
        with np.errstate(all="ignore"):
            t = q / p
        t0 = np.where(p < 0, np.maximum(t0, t), t0)
        t1 = np.where(p > 0, np.minimum(t1, t), t1)
        missed |= (p == 0) & (q < 0)
    meets = ~missed & (t0 <= t1)
    ends = np.minimum(*(np.hypot(np.maximum(np.maximum(x0 - px, px - x1), 0), np.maximum(np.maximum(y0 - py, py - y1), 0))
                        for px, py in ((ax, ay), (bx, by))))
    corners = np.minimum.reduce([_point_segment(cx, cy, ax, ay, bx, by)
                                 for cx, cy in ((x0, y0), (x1, y0), (x0, y1), (x1, y1))])
    return np.where(meets, 0.0, np.minimum(ends, corners))


def _cells_around(lo_x, lo_y, hi_x, hi_y, c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(owner, cell_x, cell_y) for every cell meeting each box [lo_x, hi_x] x [lo_y, hi_y]."""
    ix0, iy0 = np.floor(lo_x / c).astype(np.int64), np.floor(lo_y / c).astype(np.int64)
    nx = np.floor(hi_x / c).astype(np.int64) - ix0 + 1
    ny = np.floor(hi_y / c).astype(np.int64) - iy0 + 1
    count = nx * ny
    owner = np.repeat(np.arange(len(count)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return owner, ix0[owner] + offset % nx[owner], iy0[owner] + offset // nx[owner]


def _occupied(map_no: np.ndarray, cx: np.ndarray, cy: np.ndarray, occupied: pl.DataFrame) -> np.ndarray:
    """Which of the cells (map_no, cx, cy) are among ``occupied`` (map_no, cell_x, cell_y)."""
    cells = pl.DataFrame({"map_no": map_no, "cell_x": cx, "cell_y": cy}).with_row_index("i")
    found = cells.join(occupied, on=["map_no", "cell_x", "cell_y"], how="semi")["i"].to_numpy()
    mine = np.zeros(len(cx), bool)
    mine[found] = True
    return mine


def _centre_lines(index: LaneIndex) -> pl.DataFrame:
    """Centre-line segments with GEOS's start measures (``line_locate_point`` adds segment lengths in order, from 0)
    and the arc-length keys of ``index`` (a ``LaneIndex``), with the direction each key range gives."""
    key, coords, owner = index.key, index.coords, index.owner

    def direction(t: np.ndarray, lane: np.ndarray, side: str) -> np.ndarray:
        """``LaneIndex.direction`` at the shifted arc length ``t`` (side "left": just below it)."""
        i = np.searchsorted(key, t, side=side) - 1
        i = np.clip(i, index.first[lane], np.maximum(index.last[lane] - 1, index.first[lane]))
        j = np.minimum(i + 1, index.last[lane])
        d = coords[j] - coords[i]
        return np.arctan2(d[:, 1], d[:, 0])

    k = np.flatnonzero(owner[1:] == owner[:-1])  # segment k runs from vertex k to k + 1
    lane = owner[k]
    d = coords[k + 1] - coords[k]
    len2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    seg_len = np.sqrt(len2)
    start = np.zeros(len(k))
    bounds = np.r_[np.flatnonzero(np.r_[True, lane[1:] != lane[:-1]]), len(k)] if len(k) else np.zeros(1, int)
    for a, b in pairwise(bounds):  # GEOS adds the lengths one by one from 0
        start[a:b] = np.cumsum(np.r_[0.0, seg_len[a:b - 1]])
    return pl.DataFrame({
        "lane_no": lane.astype(np.int32), "seg_no": k, "ax": coords[k, 0], "ay": coords[k, 1],
        "bx": coords[k + 1, 0], "by": coords[k + 1, 1], "dx": d[:, 0], "dy": d[:, 1], "len2": len2,
        "seg_len": seg_len, "start_m": start, "shift": lane * index.span, "key_lo": key[k], "key_hi": key[k + 1],
        # a shifted arc length t picks the last vertex at or before it: below key_lo the one before, from key_hi
        # on the last vertex at key_hi, else vertex k
        "dir_before": direction(key[k], lane, "left"), "dir_mid": direction(key[k], lane, "right"),
        "dir_after": direction(key[k + 1], lane, "right"),
    })


def lane_grid(lanes: pl.DataFrame, occupied: pl.DataFrame | None = None, cell_m: float = CELL_M) -> pl.DataFrame:
    """The lane pieces by grid cell (the module docstring), for ``track_lanes.sql``: ``lane_no`` is the lane's row
    in ``lanes`` (one map, or several with their ``map_no``, each map's lanes together and in that map's order);
    with ``occupied`` (map_no, cell_x, cell_y), only those cells."""
    if lanes.is_empty():
        return pl.DataFrame()
    r, c = schema.LOCALISATION_RANGE_M, cell_m
    reach = r + SLACK_M
    keys = ["cell_x", "cell_y", "lane_no"]
    polygons = shapely.from_wkt(lanes["polygon_wkt"].to_numpy())
    lines = shapely.from_wkt(lanes["centerline_wkt"].to_numpy())
    lane_map = (lanes["map_no"] if "map_no" in lanes.columns else pl.Series([0] * lanes.height)).to_numpy()

    # boundary edges of every ring, and the cells within reach of each
    rings, ring_lane = shapely.get_rings(polygons, return_index=True)
    rc, ri = shapely.get_coordinates(rings, return_index=True)
    k = np.flatnonzero(ri[1:] == ri[:-1])
    e_lane, (ax, ay), (bx, by) = ring_lane[ri[k]], rc[k].T, rc[k + 1].T
    e, cx, cy = _cells_around(np.minimum(ax, bx) - reach, np.minimum(ay, by) - reach,
                              np.maximum(ax, bx) + reach, np.maximum(ay, by) + reach, c)
    if occupied is not None:
        mine = _occupied(lane_map[e_lane[e]], cx, cy, occupied)
        e, cx, cy = e[mine], cx[mine], cy[mine]
    x0, y0 = cx * c, cy * c
    dist = _box_segment(x0, y0, c, ax[e], ay[e], bx[e], by[e])
    near = dist <= reach
    e, cx, cy, x0, y0, dist = e[near], cx[near], cy[near], x0[near], y0[near], dist[near]
    # an upper bound of the distance to the boundary anywhere in the cell: the farthest corner from one edge
    far = np.maximum.reduce([_point_segment(px, py, ax[e], ay[e], bx[e], by[e])
                             for px, py in ((x0, y0), (x0 + c, y0), (x0, y0 + c), (x0 + c, y0 + c))])
    pairs = pl.DataFrame({"cell_x": cx, "cell_y": cy, "lane_no": e_lane[e].astype(np.int32), "edge": e,
                          "dist": dist, "far": far})

    # the reference point of each (cell, lane): the cell centre, or another point of the cell where the centre
    # lies on (or next to) the lane's boundary
    tries = ((0.5, 0.5), (0.3125, 0.6875), (0.6875, 0.3125), (0.40625, 0.21875))
    for n, (fx, fy) in enumerate(tries):
        q_dist = _point_segment((cx + fx) * c, (cy + fy) * c, ax[e], ay[e], bx[e], by[e])
        pairs = pairs.with_columns(pl.Series(f"q{n}", q_dist))
    cells = pairs.group_by(keys).agg(
        bound=pl.min_horizontal(pl.col("far").min(), pl.lit(r)) + SLACK_M,
        fit=pl.coalesce([pl.when(pl.col(f"q{n}").min() > 1e-7).then(pl.lit(n)) for n in range(len(tries))]),
    )
    if cells["fit"].null_count():
        raise ValueError("lane_grid: no reference point off the lane boundary in a cell")
    fx, fy = (np.array([t[i] for t in tries]) for i in (0, 1))
    fit = cells["fit"].to_numpy()
    cells = cells.with_columns(qx=(cells["cell_x"].to_numpy() + fx[fit]) * c,
                               qy=(cells["cell_y"].to_numpy() + fy[fit]) * c)
    cells = cells.select(*keys, "bound", "qx", "qy")
    # cells farther than the range from the boundary lie inside the polygon everywhere (kept) or outside
    deep = np.flatnonzero(~shapely.is_valid(polygons) | ~shapely.is_empty(shapely.buffer(polygons, -r)))
    if len(deep):
        b = shapely.bounds(polygons[deep])
        owner, dcx, dcy = _cells_around(b[:, 0], b[:, 1], b[:, 2], b[:, 3], c)
        if occupied is not None:
            mine = _occupied(lane_map[deep[owner]], dcx, dcy, occupied)
            owner, dcx, dcy = owner[mine], dcx[mine], dcy[mine]
        inner = pl.DataFrame({"cell_x": dcx, "cell_y": dcy, "lane_no": deep[owner].astype(np.int32)}) \
            .join(cells.select(keys), on=keys, how="anti") \
            .with_columns(qx=(pl.col("cell_x") + 0.5) * c, qy=(pl.col("cell_y") + 0.5) * c)
        cells = pl.concat([cells, inner], how="diagonal_relaxed")
    lane_no = cells["lane_no"].to_numpy()
    q_inside = shapely.contains_xy(polygons[lane_no], cells["qx"].to_numpy(), cells["qy"].to_numpy())
    cells = cells.with_columns(q_inside=pl.Series(q_inside.astype(np.int32))) \
        .filter(pl.col("bound").is_not_null() | (pl.col("q_inside") == 1))
    if cells.is_empty():
        return pl.DataFrame()

    # the edges a point of the cell needs: all within the bound, none where the cell lies inside the polygon
    # and meets no edge (every point inside, distance 0)
    edges = pairs.select(*keys, "edge", "dist").join(cells, on=keys) \
        .filter((pl.col("dist") <= pl.col("bound"))
                & ((pl.col("q_inside") == 0) | (pl.col("dist").min().over(keys) <= SLACK_M)))
    i = edges["edge"].to_numpy()
    qx, qy = edges["qx"].to_numpy(), edges["qy"].to_numpy()
    edx, edy = bx[i] - ax[i], by[i] - ay[i]
    edges = edges.select(keys).with_columns(
        e_ax=ax[i], e_ay=ay[i], e_bx=bx[i], e_by=by[i], e_dx=edx, e_dy=edy, e_len2=edx * edx + edy * edy,
        e_len=np.sqrt(edx * edx + edy * edy),
        e_q_side=np.sign(edx * (qy - ay[i]) - edy * (qx - ax[i])).astype(np.int32))

    # centre-line segments: candidates within a loose bound (the centre's distance to the line plus half the
    # diagonal), kept when within U_c of the cell, U_c the least farthest-corner distance to one candidate: every
    # point of the cell is within U_c of the line, so its nearest segments (ties included) are within U_c of it
    centre = shapely.points((cells["cell_x"].to_numpy() + 0.5) * c, (cells["cell_y"].to_numpy() + 0.5) * c)
    loose = shapely.distance(lines[cells["lane_no"].to_numpy()], centre) + c * np.sqrt(0.5) + SLACK_M
    # the arc-length keys are those of each map's own LaneIndex (its lane numbers and span)
    first = np.flatnonzero(np.r_[True, lane_map[1:] != lane_map[:-1]])
    segs = pl.concat([_centre_lines(LaneIndex(lanes[a:b])).with_columns(pl.col("lane_no") + a)
                      for a, b in pairwise(np.r_[first, lanes.height])])
    widest = cells.with_columns(loose=loose).group_by("lane_no").agg(pl.col("loose").max())
    w = segs.select("lane_no").join(widest, on="lane_no", how="left")["loose"].fill_null(0.0).to_numpy()
    sax, say, sbx, sby = (segs[name].to_numpy() for name in ("ax", "ay", "bx", "by"))
    owner, scx, scy = _cells_around(np.minimum(sax, sbx) - w, np.minimum(say, sby) - w,
                                    np.maximum(sax, sbx) + w, np.maximum(say, sby) + w, c)
    cand = pl.DataFrame({"cell_x": scx, "cell_y": scy, "lane_no": segs["lane_no"].to_numpy()[owner],
                         "seg": owner}).join(cells.select(keys), on=keys)
    i = cand["seg"].to_numpy()
    x0, y0 = cand["cell_x"].to_numpy() * c, cand["cell_y"].to_numpy() * c
    far = np.maximum.reduce([_point_segment(px, py, sax[i], say[i], sbx[i], sby[i])
                             for px, py in ((x0, y0), (x0 + c, y0), (x0, y0 + c), (x0 + c, y0 + c))])
    cand = cand.with_columns(d=_box_segment(x0, y0, c, sax[i], say[i], sbx[i], sby[i]), far=far) \
        .filter(pl.col("d") <= pl.col("far").min().over(keys) + SLACK_M)
    centre_rows = cand.select(keys).hstack(segs.drop("lane_no")[cand["seg"].to_numpy()].select(
        pl.all().name.prefix("c_")))

    # one row per (cell, lane, k): its k-th edge and k-th centre-line segment, either possibly absent; n_rows
    # rows per (cell, lane), so the query groups only where n_rows > 1
    edges = edges.with_columns(k=pl.int_range(pl.len()).over(keys))
    centre_rows = centre_rows.with_columns(k=pl.int_range(pl.len()).over(keys))
    grid = centre_rows.join(edges, on=[*keys, "k"], how="full", coalesce=True) \
        .join(cells.select(*keys, "q_inside", "qx", "qy"), on=keys) \
        .with_columns(n_rows=pl.len().over(keys)).drop("k")
    grid = grid.with_columns(map_no=pl.Series(lane_map[grid["lane_no"].to_numpy()], dtype=pl.Int32))
    return grid.rename({c: c.replace("_ax", "_a_x").replace("_ay", "_a_y").replace("_bx", "_b_x")
                        .replace("_by", "_b_y") for c in grid.columns})  # "by" is an SQL keyword


def insert_track_lanes(con: duckdb.DuckDBPyConnection, lanes: pl.DataFrame, grid: pl.DataFrame | None = None) -> None:
    """Insert into ``track_lanes`` the rows of ``tracks`` for the drives in ``_drive_maps`` (drive_id, map_no)
    against ``lanes`` (the lanes of those maps, each map's together, with their map_no; one map without it)."""
    if lanes.is_empty():
        return
    params = {"cells_per_m": 1.0 / CELL_M, "range_m": schema.LOCALISATION_RANGE_M}
    if grid is None:
        occupied = con.sql((SQL / "track_cells.sql").read_text(), params={"cells_per_m": params["cells_per_m"]}).pl()
        grid = lane_grid(lanes, occupied.cast({"map_no": pl.Int32, "cell_x": pl.Int64, "cell_y": pl.Int64}))
    if grid.is_empty():
        return
    con.register("lane_grid", grid)
    con.register("lane_names", pl.DataFrame({"lane_no": np.arange(lanes.height, dtype=np.int32),
                                             "lane_id": lanes["lane_id"]}))
    try:
        con.execute("insert into track_lanes by name " + (SQL / "track_lanes.sql").read_text(), params)
    finally:
        con.unregister("lane_grid")
        con.unregister("lane_names")


def join_locate(tracks: pl.DataFrame, lanes: pl.DataFrame) -> pl.DataFrame:
    """Rows of ``track_lanes`` for ``tracks`` (drives on one map) against ``lanes`` (that map), on an in-memory
    DuckDB, as ``benchmarks.shapely_lanes.shapely_locate`` gives them."""
    con = duckdb.connect()
    try:
        tables.create_table(con, schema.TRACK_LANES)
        frame = tracks if "kind" in tracks.columns else tracks.with_columns(kind=pl.lit("vehicle"))
        con.register("tracks", frame)
        con.register("_drive_maps", frame.select(pl.col("drive_id").unique(), map_no=pl.lit(0, pl.Int32)))
        insert_track_lanes(con, lanes)
        return con.sql("select * from track_lanes").pl().cast(schema.TRACK_LANES.polars_schema)
    finally:
        con.close()


def main(argv: list[str] | None = None) -> dict[str, object]:
    """Old (the shapely look-up map by map, as ingest ran it before issue 33 but on one thread, and the insert of
    its rows) against new (the grid, then ``track_lanes.sql``: map by map, and for all maps at once as one ingest
    batch) on the base drives, in one process: CPU and wall seconds, and whether the rows agree."""
    from benchmarks.tiers import WORK

    base = Path((argv or sys.argv[1:] or [str(WORK / "base")])[0])
    drives = pl.read_parquet(base / "drive_inputs.parquet").filter(pl.col("status") == "ingested")
    maps = drives.select(pl.col("map_id").unique(maintain_order=True)).with_row_index("map_no") \
        .with_columns(pl.col("map_no").cast(pl.Int32))
    lanes = pl.read_parquet(base / "lanes.parquet").join(maps, on="map_id").sort("map_no", maintain_order=True)
    tracks = pl.read_parquet(base / "tracks.parquet",
                             columns=["drive_id", "actor_id", "kind", "frame", "x_m", "y_m", "heading_rad"])
    drive_maps = drives.select("drive_id", "map_id").join(maps, on="map_id")
    tracks = tracks.join(drive_maps.select("drive_id", "map_id"), on="drive_id")
    cons = {name: duckdb.connect() for name in ("old", "new, map by map", "new, one batch")}
    for con in cons.values():
        tables.create_table(con, schema.TRACK_LANES)
    spent: dict[str, list[float]] = {}

    def timed(name: str, fn, *args):
        cpu, wall = time.process_time(), time.perf_counter()
        out = fn(*args)
        total = spent.setdefault(name, [0.0, 0.0])
        total[0] += time.process_time() - cpu
        total[1] += time.perf_counter() - wall
        return out

    con = cons["new, map by map"]
    for (map_id,), on_map in tracks.group_by("map_id", maintain_order=True):
        ln = lanes.filter(pl.col("map_id") == map_id).drop("map_no")
        timed("old", lambda t=on_map, m=ln: tables.insert(cons["old"], "track_lanes", reference_locate(t, m)))
        con.register("tracks", on_map)
        con.register("_drive_maps", on_map.select(pl.col("drive_id").unique(), map_no=pl.lit(0, pl.Int32)))
        occupied = con.sql((SQL / "track_cells.sql").read_text(), params={"cells_per_m": 1.0 / CELL_M}).pl()
        grid = timed("new, map by map: grid", lane_grid, ln, occupied.cast({"map_no": pl.Int32, "cell_x": pl.Int64,
                                                                            "cell_y": pl.Int64}))
        timed("new, map by map: SQL", insert_track_lanes, con, ln, grid)
    con = cons["new, one batch"]
    con.register("tracks", tracks)
    con.register("_drive_maps", drive_maps.select("drive_id", "map_no"))
    occupied = timed("new, one batch: cells", lambda: con.sql(
        (SQL / "track_cells.sql").read_text(), params={"cells_per_m": 1.0 / CELL_M}).pl())
    grid = timed("new, one batch: grid", lane_grid, lanes, occupied.cast({"map_no": pl.Int32, "cell_x": pl.Int64,
                                                                          "cell_y": pl.Int64}))
    timed("new, one batch: SQL", insert_track_lanes, con, lanes, grid)
    report: dict[str, object] = {"rows": tracks.height, "maps": maps.height, "grid rows (one batch)": grid.height}
    key = ["drive_id", "actor_id", "frame", "lane_id"]
    old = cons["old"].sql("select * from track_lanes").pl()
    report["pairs, old"] = old.height
    for name in ("new, map by map", "new, one batch"):
        new = cons[name].sql("select * from track_lanes").pl()
        both = old.join(new, on=key, how="full", coalesce=True, suffix="_new")
        report[f"pairs, {name}"] = new.height
        report[f"{name}: rows missing on a side"] = both.filter(
            pl.col("dist_m").is_null() | pl.col("dist_m_new").is_null()).height
        report[f"{name}: dist_m off by > 1e-9"] = int(((both["dist_m"] - both["dist_m_new"]).abs() > 1e-9).sum())
        report[f"{name}: heading off by > 1e-9"] = int(
            ((both["heading_diff_rad"] - both["heading_diff_rad_new"]).abs() > 1e-9).sum())
    for name, (cpu, wall) in spent.items():
        report[f"{name}: CPU s / wall s"] = f"{cpu:.2f} / {wall:.2f}"
    for name, value in report.items():
        print(f"{name:45} {value}")
    return report


if __name__ == "__main__":
    main()
