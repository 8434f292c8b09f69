"""Map localisation: which lanes each track row lies in or near, by a compiled look-up over a per-map grid.

For every track row of a moving kind (static kinds such as cones are skipped), every lane polygon within
``LOCALISATION_RANGE_M`` (3 m) of the box centre is kept with its distance (0 inside) and the heading difference
to the lane direction: the direction of the centre-line segment at the point's arc length along the centre line.
Each row's best lane is marked (``best_lane``: of its lanes within 90 degrees of its heading, the nearest, then the
best aligned, then the smallest id); scenarios apply their own ``lane_calculation_tolerance_length`` to it in SQL
(``queries/relations/actor_lanes.sql``). docs/localisation.md gives the formulas.

The numbers are those of GEOS (through shapely) computed the same way, operation for operation:
- candidates: the lanes whose bounding box grown by the range holds the point (both ends included; strictly
  inside for an invalid polygon, as shapely's reach test had it), found through a uniform grid of cells that
  lists every lane whose grown box meets the cell;
- inside: the even-odd rule over every ring's edges (a ray towards +x), as GEOS's point-in-area locator counts
  crossings; only a point within rounding of the boundary can be judged otherwise, and there the distance is 0 up
  to that rounding;
- distance: 0 inside, else the least of GEOS's ``Distance::pointToSegment`` over the boundary edges;
- arc length: GEOS's ``LengthIndexOfPoint`` (``line_locate_point``): the first segment of least distance, the
  start measure plus the projection on it, clamped to the segment;
- direction: the segment whose cumulated-length key holds that arc length (``LaneIndex.key``, a binary search).
Edges and centre-line segments are grouped in runs of ``RUN`` with their bounding boxes; a run whose box cannot
hold a nearer edge (or a crossing of the ray) is skipped whole, which changes no result.

The kernel is compiled with numba (``nogil``): chunks of points run on a thread pool. A ``LaneIndex`` is plain
numpy arrays, so it pickles (e.g. to Spark executors) and is safe to share between threads.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.compute as pc
import shapely

from logiq_sql.core import schema

STATIC_KINDS = ("object", "fod", "sign")
CHUNK_POINTS = 250_000  # bounds the memory of one chunk's output
MIN_CHUNK_POINTS = 10_000  # smaller drives are not split between threads
WORKERS = min(os.cpu_count() or 1, 4)  # chunks localised at once
RUN = 8  # edges (and centre-line segments) per bounding box
CELL_M = 4.0  # grid cell side; grown for maps so large that the grid would exceed MAX_CELLS
MAX_CELLS = 4_000_000
SLACK_M = 1e-6  # a run is skipped only when its box is farther than this beyond what could matter (rounding)


def _runs(owner: np.ndarray, n_lanes: int, ax, ay, bx, by):
    """Runs of up to RUN consecutive pieces of one lane: (first piece of each run and one past the last, the runs'
    boxes x0 y0 x1 y1, each lane's first run and one past its last)."""
    lane_first = np.searchsorted(owner, np.arange(n_lanes + 1))
    pos = np.arange(len(owner)) - lane_first[owner]
    start = np.flatnonzero(pos % RUN == 0)
    bounds = np.r_[start, len(owner)].astype(np.int64)
    if len(start):
        box = [np.minimum.reduceat(np.minimum(ax, bx), start), np.minimum.reduceat(np.minimum(ay, by), start),
               np.maximum.reduceat(np.maximum(ax, bx), start), np.maximum.reduceat(np.maximum(ay, by), start)]
    else:
        box = [np.zeros(0)] * 4
    lane_runs = np.searchsorted(owner[start], np.arange(n_lanes + 1)).astype(np.int64)
    return bounds, np.stack(box), lane_runs


def arc_length_keys(lines: np.ndarray):
    """The centre lines' vertices and, for the direction look-up, their cumulated lengths as sorted keys: (vertex
    coordinates, each vertex's lane, span, keys = arc length + lane * span, each lane's first and last vertex or
    -1)."""
    coords, owner = shapely.get_coordinates(lines, return_index=True)
    cum = np.cumsum(np.r_[0.0, np.hypot(*np.diff(coords, axis=0).T)])
    starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    arc = cum - np.repeat(cum[starts], np.diff(np.r_[starts, len(coords)]))  # restarts on each line
    span = float(arc.max() if len(arc) else 0.0) + 1.0
    first, last = np.full(len(lines), -1), np.full(len(lines), -1)
    first[owner[starts]] = starts
    last[owner[np.r_[starts[1:] - 1, len(coords) - 1]]] = np.r_[starts[1:] - 1, len(coords) - 1]
    return coords, owner, span, arc + owner * span, first, last


def _probe() -> int:
    return 0


def _cache_writable() -> bool:
    """Whether numba can cache machine code here: beside the module, in NUMBA_CACHE_DIR or in the user's cache
    (not, e.g., on an executor with a zipped package and no writable home)."""
    try:
        return numba.njit(cache=True)(_probe)() == 0
    except Exception:  # numba raises OSError, RuntimeError or its own errors when no cache can be written
        return False


_CACHE = _cache_writable()


def _compiled(fn):
    """``fn`` compiled without the GIL and with IEEE division (x / 0 is inf or NaN, as in GEOS), its machine code
    cached where it can be (else compiled on each start)."""
    return numba.njit(cache=_CACHE, nogil=True, error_model="numpy")(fn)


class LaneIndex:
    """The lanes of one map as arrays: grown boxes, boundary edges and centre-line segments in runs, the
    arc-length keys of the centre lines, and the grid of cells listing the lanes whose grown box meets each."""

    def __init__(self, lanes: pl.DataFrame):
        self.lane_ids = lanes["lane_id"]
        n = lanes.height
        polygons = shapely.from_wkt(lanes["polygon_wkt"].to_numpy())
        lines = shapely.from_wkt(lanes["centerline_wkt"].to_numpy())
        r = schema.LOCALISATION_RANGE_M
        b = shapely.bounds(polygons)
        self.box = np.stack([b[:, 0] - r, b[:, 1] - r, b[:, 2] + r, b[:, 3] + r])  # NaN for an empty polygon
        # shapely's look-up took an invalid polygon's reach to be this box, which does not contain its boundary:
        # a point exactly 3 m beside such a lane, level with its edge, was not kept; nor is it here
        self.open_box = ~shapely.is_valid(polygons)

        # boundary edges of every ring, lane by lane
        rings, ring_lane = shapely.get_rings(polygons, return_index=True)
        rc, ri = shapely.get_coordinates(rings, return_index=True)
        k = np.flatnonzero(ri[1:] == ri[:-1])
        self.edges = np.stack([rc[k, 0], rc[k, 1], rc[k + 1, 0], rc[k + 1, 1]])
        self.edge_runs, self.edge_box, self.lane_edge_runs = _runs(ring_lane[ri[k]], n, *self.edges)

        # centre lines: vertices, the arc-length keys of the direction look-up, segments with GEOS's start measures
        self.coords, self.owner, self.span, self.key, self.first, self.last = arc_length_keys(lines)
        coords, owner = self.coords, self.owner
        s = np.flatnonzero(owner[1:] == owner[:-1])  # segment s runs from vertex s to s + 1
        seg_lane = owner[s]
        d = coords[s + 1] - coords[s]
        seg_len = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
        measure = np.zeros(len(s))  # GEOS adds the segment lengths one by one from 0 on each line
        lane_seg = np.searchsorted(seg_lane, np.arange(n + 1))
        for lane in np.flatnonzero(np.diff(lane_seg) > 1):  # once per lane at build, not per row
            a, z = lane_seg[lane], lane_seg[lane + 1]
            measure[a:z] = np.cumsum(np.r_[0.0, seg_len[a:z - 1]])
        self.segments = np.stack([coords[s, 0], coords[s, 1], coords[s + 1, 0], coords[s + 1, 1], seg_len, measure])
        self.seg_runs, self.seg_box, self.lane_seg_runs = _runs(seg_lane, n, *self.segments[:4])

        # the grid: every lane listed in each cell its grown box meets
        usable = np.flatnonzero(np.isfinite(self.box).all(axis=0))
        x0, y0, x1, y1 = self.box[:, usable]
        ox, oy = (float(x0.min()), float(y0.min())) if len(usable) else (0.0, 0.0)
        width, height = (float(x1.max()) - ox, float(y1.max()) - oy) if len(usable) else (0.0, 0.0)
        cell = max(CELL_M, math.sqrt(width * height / MAX_CELLS))
        cx0, cy0 = np.floor((x0 - ox) / cell).astype(np.int64), np.floor((y0 - oy) / cell).astype(np.int64)
        cx1, cy1 = np.floor((x1 - ox) / cell).astype(np.int64), np.floor((y1 - oy) / cell).astype(np.int64)
        nx, ny = (int(cx1.max()) + 1, int(cy1.max()) + 1) if len(usable) else (0, 0)
        wide, count = cx1 - cx0 + 1, (cx1 - cx0 + 1) * (cy1 - cy0 + 1)
        lane = np.repeat(np.arange(len(usable)), count)
        offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        cells = (cy0[lane] + offset // wide[lane]) * nx + cx0[lane] + offset % wide[lane]
        order = np.argsort(cells, kind="stable")  # lanes in map order within a cell
        self.cell_lanes = usable[lane[order]].astype(np.int64)
        self.cell_first = np.searchsorted(cells[order], np.arange(nx * ny + 1)).astype(np.int64)
        self.grid = np.array([ox, oy, cell, nx, ny])

    def locate(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray):
        """(row index, lane index, distance to polygon, heading minus lane direction) for every pair in range."""
        x, y, heading = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, heading))
        parts, start, capacity = [], 0, 4 * len(x) + 16
        while start < len(x):  # one pass unless the output outgrows its buffer; then the rest in a bigger one
            out_i = np.empty((2, capacity), np.int64)
            out_f = np.empty((2, capacity), np.float64)
            written, start = _locate(
                x, y, heading, start, float(schema.LOCALISATION_RANGE_M), self.grid, self.cell_first,
                self.cell_lanes, self.box, self.open_box, self.edges, self.edge_runs, self.edge_box, self.lane_edge_runs,
                self.segments, self.seg_runs, self.seg_box, self.lane_seg_runs, self.key,
                self.span, self.coords, self.first, self.last, out_i, out_f)
            parts.append((out_i[:, :written], out_f[:, :written]))
            capacity *= 2
        if not parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
        i = np.concatenate([p[0] for p in parts], axis=1)
        f = np.concatenate([p[1] for p in parts], axis=1)
        return i[0], i[1], f[0], f[1]


@_compiled
def _point_segment(px, py, ax, ay, bx, by):
    """GEOS's Distance::pointToSegment, operation for operation."""
    if ax == bx and ay == by:
        return math.sqrt((px - ax) * (px - ax) + (py - ay) * (py - ay))
    len2 = (bx - ax) * (bx - ax) + (by - ay) * (by - ay)
    r = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / len2
    if r <= 0.0:
        return math.sqrt((px - ax) * (px - ax) + (py - ay) * (py - ay))
    if r >= 1.0:
        return math.sqrt((px - bx) * (px - bx) + (py - by) * (py - by))
    s = ((ay - py) * (bx - ax) - (ax - px) * (by - ay)) / len2
    return abs(s) * math.sqrt(len2)


@_compiled
def _box_distance(px, py, box, k):
    """Distance from a point to the k-th box (0 inside): no piece in the box is nearer."""
    dx = max(box[0, k] - px, 0.0, px - box[2, k])
    dy = max(box[1, k] - py, 0.0, py - box[3, k])
    return math.sqrt(dx * dx + dy * dy)


@_compiled
def _inside(px, py, lane, edges, edge_runs, edge_box, lane_edge_runs):
    """The even-odd rule over the lane's edges: crossings of the ray from the point towards +x."""
    odd = False
    for k in range(lane_edge_runs[lane], lane_edge_runs[lane + 1]):
        if edge_box[1, k] > py or edge_box[3, k] <= py or edge_box[2, k] < px:
            continue  # no edge of the run straddles the ray's line, or all lie left of the point
        for e in range(edge_runs[k], edge_runs[k + 1]):
            ax, ay, bx, by = edges[0, e], edges[1, e], edges[2, e], edges[3, e]
            if (ay > py) != (by > py):
                side = (bx - ax) * (py - ay) - (px - ax) * (by - ay)  # > 0: the point left of a -> b
                if (side > 0.0) if by > ay else (side < 0.0):
                    odd = not odd
    return odd


@_compiled
def _edge_distance(px, py, lane, reach, edges, edge_runs, edge_box, lane_edge_runs):
    """The least distance to the lane's edges, exact where it is at most ``reach`` (else some value above it)."""
    best = np.inf
    for k in range(lane_edge_runs[lane], lane_edge_runs[lane + 1]):
        if _box_distance(px, py, edge_box, k) > min(best, reach) + SLACK_M:
            continue
        for e in range(edge_runs[k], edge_runs[k + 1]):
            best = min(best, _point_segment(px, py, edges[0, e], edges[1, e], edges[2, e], edges[3, e]))
    return best


@_compiled
def _arc_length(px, py, lane, segments, seg_runs, seg_box, lane_seg_runs):
    """GEOS's LengthIndexOfPoint: the arc length at the first centre-line segment of least distance."""
    best, measure = np.inf, 0.0
    for k in range(lane_seg_runs[lane], lane_seg_runs[lane + 1]):
        if _box_distance(px, py, seg_box, k) > best + SLACK_M:
            continue  # every segment of the run is farther than the best so far: none replaces it
        for s in range(seg_runs[k], seg_runs[k + 1]):
            ax, ay, bx, by = segments[0, s], segments[1, s], segments[2, s], segments[3, s]
            d = _point_segment(px, py, ax, ay, bx, by)
            if d < best:
                best = d
                # GEOS's LineSegment::projectionFactor, then the measure clamped to the segment
                if px == ax and py == ay:
                    f = 0.0
                elif px == bx and py == by:
                    f = 1.0
                else:
                    dx, dy = bx - ax, by - ay
                    f = ((px - ax) * dx + (py - ay) * dy) / (dx * dx + dy * dy)
                if f <= 0.0:
                    measure = segments[5, s]
                elif f <= 1.0:
                    measure = segments[5, s] + f * segments[4, s]
                else:
                    measure = segments[5, s] + segments[4, s]
    return measure


@_compiled
def _direction(lane, s, key, span, coords, first, last):
    """Heading of the centre-line segment of ``lane`` whose keys hold arc length ``s`` (searchsorted, side right)."""
    t = s + lane * span
    lo, hi = 0, len(key)
    while lo < hi:
        mid = (lo + hi) // 2
        if key[mid] <= t:
            lo = mid + 1
        else:
            hi = mid
    i = min(max(lo - 1, first[lane]), max(last[lane] - 1, first[lane]))
    j = min(i + 1, last[lane])
    return math.atan2(coords[j, 1] - coords[i, 1], coords[j, 0] - coords[i, 0])


@_compiled
def _locate(x, y, heading, start, reach, grid, cell_first, cell_lanes, box, open_box, edges, edge_runs, edge_box,
            lane_edge_runs, segments, seg_runs, seg_box, lane_seg_runs, key, span, coords, first,
            last, out_i, out_f):
    """Pairs from point ``start`` on, written to out_i (row, lane) and out_f (distance, heading difference) until
    a point's pairs might not fit: (pairs written, first point not done)."""
    ox, oy, cell, nx, ny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
    capacity = out_i.shape[1]
    n = 0
    for p in range(start, len(x)):
        px, py = x[p], y[p]
        fx, fy = (px - ox) / cell, (py - oy) / cell
        if not (0.0 <= fx < nx and 0.0 <= fy < ny):  # off the grid, or NaN
            continue
        c = int(fy) * nx + int(fx)  # floor: both are >= 0
        if n + cell_first[c + 1] - cell_first[c] > capacity:
            return n, p
        for m in range(cell_first[c], cell_first[c + 1]):
            lane = cell_lanes[m]
            if not (box[0, lane] <= px <= box[2, lane] and box[1, lane] <= py <= box[3, lane]):
                continue
            if open_box[lane] and not (box[0, lane] < px < box[2, lane] and box[1, lane] < py < box[3, lane]):
                continue
            if _inside(px, py, lane, edges, edge_runs, edge_box, lane_edge_runs):
                dist = 0.0
            else:
                dist = _edge_distance(px, py, lane, reach, edges, edge_runs, edge_box, lane_edge_runs)
                if not dist <= reach:
                    continue
            s = _arc_length(px, py, lane, segments, seg_runs, seg_box, lane_seg_runs)
            d = heading[p] - _direction(lane, s, key, span, coords, first, last)
            out_i[0, n], out_i[1, n] = p, lane
            out_f[0, n], out_f[1, n] = dist, math.atan2(math.sin(d), math.cos(d))
            n += 1
    return n, len(x)


@_compiled
def _best_lanes(row, rank, dist, diff):
    """For pairs grouped by row (each row's pairs consecutive): true at each row's best lane, the least by
    (dist, |diff|, rank) of its pairs with |diff| < pi/2, as actor_lanes ranked them in SQL; false elsewhere."""
    best = np.zeros(len(row), dtype=np.bool_)
    half_pi = math.pi / 2
    start = 0
    while start < len(row):
        end = start
        pick = -1
        while end < len(row) and row[end] == row[start]:
            if abs(diff[end]) < half_pi and (pick < 0 or (dist[end], abs(diff[end]), rank[end])
                                             < (dist[pick], abs(diff[pick]), rank[pick])):
                pick = end
            end += 1
        if pick >= 0:
            best[pick] = True
        start = end
    return best


def locate(tracks: pl.DataFrame, lanes: pl.DataFrame, index: LaneIndex | None = None) -> pl.DataFrame:
    """Rows of ``track_lanes`` for ``tracks`` (drives on one map) against ``lanes`` (that map)."""
    return locate_maps([(tracks, lanes, index)])


def locate_maps(parts: list[tuple[pl.DataFrame, pl.DataFrame, LaneIndex | None]]) -> pl.DataFrame:
    """Rows of ``track_lanes`` for each (tracks of drives on one map, that map's lanes, its index or None to build
    it), in the order given (``track_lanes_of`` over the frames one after the other)."""
    rows = pl.concat([tracks for tracks, *_ in parts], how="vertical_relaxed")
    ends = np.cumsum([0] + [tracks.height for tracks, *_ in parts])
    table = track_lanes_of(rows.to_arrow(), [(np.arange(a, z), lanes, index)
                                              for (_, lanes, index), a, z in zip(parts, ends[:-1], ends[1:], strict=True)])
    carry = [c for c in table.column_names if c not in ("drive_id", "actor_id", "lane_id")]
    # the look-up's strings are dictionaries over the rows' and the lanes' own (track_lanes_of): plain strings here
    return pl.from_arrow(table.set_column(0, "drive_id", table["drive_id"].cast(pa.string()))
                         .set_column(1, "actor_id", table["actor_id"].cast(pa.string()))
                         .set_column(3, "lane_id", table["lane_id"].cast(pa.string()))).select(
        *table.column_names).cast({c: schema.STORED_TRACK_LANES.polars_schema[c] for c in carry}
                                  | schema.TRACK_LANES.polars_schema)


def build_indexes(lanes: list[pl.DataFrame]) -> list[LaneIndex]:
    """The index of each map's lanes, built on a thread pool."""
    with ThreadPoolExecutor(WORKERS) as pool:
        return list(pool.map(LaneIndex, lanes))


def track_lanes_of(rows: pa.Table, maps: list[tuple[np.ndarray, pl.DataFrame, LaneIndex | None]]) -> pa.Table:
    """Rows of ``track_lanes`` (Arrow) for ``rows`` (track rows: drive_id, actor_id, kind, frame, x_m, y_m,
    heading_rad, and the integer keys schema.TRACK_KEYS when it has them). ``maps`` gives for each map the
    indices of its rows in ``rows`` (increasing), its lanes, and its index (None: built here); rows of a static
    kind are skipped. The pairs come map after map in that order, each map's in the order of its rows; each
    carries its row's drive_id, actor_id, frame and keys.

    Every map's chunks run on one thread pool. drive_id, actor_id and lane_id are Arrow dictionaries over the
    rows' and the lanes' own strings (no string is copied here; DuckDB stores them as strings)."""
    kind = rows["kind"]
    static = pc.is_in(kind, value_set=pa.array(STATIC_KINDS, type=kind.type))
    moving = pc.and_(pc.is_valid(kind), pc.invert(static)).to_numpy()
    work = [(found, lanes, index) for found, lanes, index in ((idx[moving[idx]], lanes, index)
                                                              for idx, lanes, index in maps)
            if len(found) and not lanes.is_empty()]
    keys = [k.name for k in schema.TRACK_KEYS if k.name in rows.column_names]
    names = [*schema.TRACK_LANES.column_names, *keys, schema.BEST_LANE.name]
    if not work:
        types = schema.STORED_TRACK_LANES.polars_schema
        return pa.Table.from_pylist([], schema=pa.schema([(c, schema.arrow_type(types[c])) for c in names]))
    x, y, heading = (rows[c].to_numpy() for c in ("x_m", "y_m", "heading_rad"))

    def chunk_lanes(task) -> tuple[np.ndarray, ...]:
        idx, index, first_lane = task
        row, lane, dist, diff = index.locate(x[idx], y[idx], heading[idx])
        return idx[row], lane + first_lane, dist, diff

    built = iter(build_indexes([lanes for _, lanes, index in work if index is None]))
    indexes = [index if index is not None else next(built) for *_, index in work]
    with ThreadPoolExecutor(WORKERS) as pool:
        total = sum(len(idx) for idx, *_ in work)
        size = min(CHUNK_POINTS, max(MIN_CHUNK_POINTS, -(-total // WORKERS)))  # every worker busy
        first_lane = np.cumsum([0] + [len(index.lane_ids) for index in indexes])
        tasks = [(idx[start:start + size], index, first) for (idx, *_), index, first in
                 zip(work, indexes, first_lane[:-1], strict=True) for start in range(0, len(idx), size)]
        row, lane, dist, diff = (np.concatenate(a) for a in zip(*pool.map(chunk_lanes, tasks), strict=True))
    lane_ids = pl.concat([index.lane_ids for index in indexes]).cast(pl.String).to_arrow().cast(pa.string())
    # each lane's place in lane_id order (byte order, as DuckDB sorts strings): the last tie-break of the best lane
    rank = np.empty(len(lane_ids), dtype=np.int64)
    rank[pc.sort_indices(lane_ids).to_numpy()] = np.arange(len(lane_ids))
    at = pa.array(row.astype(np.int32, copy=False))  # a batch holds far fewer than 2^31 rows
    columns = {
        "drive_id": _strings_of(rows, "drive_id", ("drive_key",), row, at),
        "actor_id": _strings_of(rows, "actor_id", ("drive_key", "actor_key"), row, at),
        "frame": rows["frame"].take(at),
        "lane_id": pa.DictionaryArray.from_arrays(pa.array(lane.astype(np.int32)), lane_ids),
        "dist_m": pa.array(dist), "heading_diff_rad": pa.array(diff),
        schema.BEST_LANE.name: pa.array(_best_lanes(row, rank[lane], dist, diff)),
    } | {k: rows[k].take(at) for k in keys}
    return pa.table([columns[c] for c in names], names=names)


def _strings_of(rows: pa.Table, column: str, keys: tuple[str, ...], row: np.ndarray, at: pa.Array) -> pa.Array:
    """``column`` of the rows ``row`` (``at``: the same as Arrow) as a dictionary. With the integer ``keys`` that
    tell its runs apart (a drive's rows, a track's), the dictionary holds one string per run of rows: DuckDB writes
    such a column for less CPU than one over every row's string, which it is without the keys."""
    if not all(k in rows.column_names for k in keys):
        return pa.DictionaryArray.from_arrays(at, rows[column].combine_chunks())
    key = [rows[k].to_numpy() for k in keys]
    start = np.ones(rows.num_rows, dtype=bool)
    start[1:] = np.logical_or.reduce([k[1:] != k[:-1] for k in key])
    run = np.cumsum(start, dtype=np.int64) - 1
    firsts = np.flatnonzero(start)
    return pa.DictionaryArray.from_arrays(pa.array(run[row].astype(np.int32)),
                                          rows[column].take(pa.array(firsts)).combine_chunks())
