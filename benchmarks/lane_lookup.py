"""The lane look-up alone, old and new, on a tier's Parquet (issue 33):

    python -m benchmarks.lane_lookup --tier S     # after `make bench TIER=S` (or benchmarks.tiers) wrote its Parquet

Every moving track row against the lanes of its drive's map, map by map, the rows of a map split between two
threads, as ``benchmarks.components`` counts localisation:

    new      logiq_sql.ingestion.localise: LaneIndex built per map, then its compiled look-up (arrays out)
    new+rows logiq_sql.ingestion.localise.locate, as ingest calls it: the same plus the track_lanes frame (ids gathered),
             its rows split between localise.WORKERS threads
    old      benchmarks/shapely_lanes.py, the shapely look-up ingest used before (arrays out)

Both sides' (row, lane) pairs are compared: the run fails unless they are the same, with distances and heading
differences within 1e-9. Prints wall and CPU seconds, microseconds per row, and old / new.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor

import duckdb
import numpy as np
import polars as pl

from benchmarks.shapely_lanes import ShapelyLanes
from benchmarks.tiers import WORK
from logiq_sql.ingestion.localise import STATIC_KINDS, LaneIndex, locate


def maps(parquet) -> list[tuple[pl.DataFrame, pl.DataFrame]]:
    """(moving rows, lanes) of every map of the tier."""
    with duckdb.connect() as con:
        rows = con.sql("""
            select d.map_id, t.drive_id, t.actor_id, t.frame, t.kind, t.x_m, t.y_m, coalesce(t.heading_rad, 0) as heading_rad
            from read_parquet($tracks) as t inner join read_parquet($drives) as d on t.drive_id = d.drive_id
            where not list_contains($static_kinds, t.kind) order by d.map_id, t.drive_id, t.actor_id, t.frame""",
            params={"tracks": str(parquet / "tracks.parquet"), "drives": str(parquet / "drives.parquet"),
                    "static_kinds": list(STATIC_KINDS)}).pl()
    lanes = pl.read_parquet(parquet / "lanes.parquet")
    return [(on_map, lanes.filter(pl.col("map_id") == map_id))
            for (map_id,), on_map in rows.partition_by("map_id", as_dict=True, maintain_order=True).items()]


def two_threads(make, parts: list[tuple[pl.DataFrame, pl.DataFrame]], pool: ThreadPoolExecutor) -> list:
    """``make(lanes)`` per map, then its ``locate`` over each half of the map's rows on a thread of its own."""
    out = []
    for rows, lanes in parts:
        if lanes.is_empty():
            out.append(None)
            continue
        index = make(lanes)
        half = rows.height // 2
        halves = [rows.slice(0, half), rows.slice(half)]
        found = list(pool.map(lambda r: index.locate(r["x_m"].to_numpy(), r["y_m"].to_numpy(),
                                                     r["heading_rad"].to_numpy()), halves))
        out.append([np.r_[found[0][0], found[1][0] + half], *(np.r_[a, b] for a, b in zip(found[0][1:], found[1][1:]))])
    return out


def timed(fn) -> tuple[object, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = fn()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def same(old: list, new: list) -> int:
    """Pairs on both sides; raises unless they agree (pairs, distances, heading differences within 1e-9)."""
    total = 0
    for a, b in zip(old, new):
        if a is None:
            continue
        frames = [pl.DataFrame({"row": r, "lane": ln, f"d{i}": d, f"h{i}": h}) for i, (r, ln, d, h) in enumerate((a, b))]
        both = frames[0].join(frames[1], on=["row", "lane"], how="full", coalesce=True)
        turn = (pl.col("h0") - pl.col("h1")).abs()
        bad = both.filter(pl.col("d0").is_null() | pl.col("d1").is_null() | ((pl.col("d0") - pl.col("d1")).abs() > 1e-9)
                          | (pl.min_horizontal(turn, 2 * np.pi - turn) > 1e-9))
        if not bad.is_empty():
            raise SystemExit(f"the look-ups differ:\n{bad}")
        total += frames[0].height
    return total


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", default="S")
    args = parser.parse_args(argv)
    parquet = WORK / args.tier / "parquet"
    if not (parquet / "tracks.parquet").exists():
        raise SystemExit(f"{parquet} not found: run `make bench TIER={args.tier}` first.")
    parts = maps(parquet)
    rows = sum(r.height for r, _ in parts)
    report = {}
    with ThreadPoolExecutor(2) as pool:
        two_threads(LaneIndex, parts[:1], pool)  # compiles (or loads) the kernel before timing
        new, *report["new"] = timed(lambda: two_threads(LaneIndex, parts, pool))
        _, *report["new+rows"] = timed(lambda: [locate(r, lanes) for r, lanes in parts])
        old, *report["old"] = timed(lambda: two_threads(ShapelyLanes, parts, pool))
    pairs = same(old, new)
    print(f"tier {args.tier}: {rows:,} moving rows, {len(parts)} maps, {pairs:,} (row, lane) pairs, the same on both"
          f" sides (distances and heading differences within 1e-9)")
    for name, (wall, cpu) in report.items():
        print(f"{name:9} {wall:7.2f} s wall {cpu:7.2f} s CPU {1e6 * wall / rows:6.3f} us/row wall"
              f" {1e6 * cpu / rows:6.3f} us/row CPU")
    print(f"old / new: {report['old'][0] / report['new'][0]:.1f}x wall, {report['old'][1] / report['new'][1]:.1f}x CPU")
    return report


if __name__ == "__main__":
    main()
