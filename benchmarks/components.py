"""What the pipeline's unavoidable parts cost on their own, as ratios to the floor measured in the same run.

    python -m benchmarks.components --tier M      # after `make bench TIER=M` wrote benchmarks/work/M/parquet
    python -m benchmarks.components --tier M --ingest   # also logiq_sql's ingest of it, against its own parts

Each part is the least a pipeline of this kind must do, written as one plain DuckDB statement over the tier's
tracks.parquet with nothing of logiq_sql around it but its constants (the static kinds, the chunk size);
localisation is logiq_sql.ingestion.localise's look-up over it and lanes.parquet:

    floor          the benchmark floor: scan + group-by over the track columns (benchmarks/tiers.py)
    window         one per-actor window (the previous sample), the least that speeds, headings, lane runs and
                   phase islands need; summed so that nothing is written
    write          the tracks written once into a DuckDB file (what ingest must do so that matching can rerun)
    pair join      every 10th actor paired with every actor of its frame within 200 m (the relation range),
                   counted only: the least work behind any ego-actor relation; an equi-join on (drive, frame, x
                   band) as relations.sql pairs them (bands of 201 m, each ego row probing its band and the two
                   beside it: the cheapest pairing measured, benchmarks/README.md)
    localisation   every moving row's lanes within 3 m, with distance and heading difference: ingest's own
                   look-up (logiq_sql.ingestion.localise, compiled: its index built per map, then the pairs as arrays), no
                   rows written; both cores (a thread each over half of a map's rows); the rows are read from the
                   Parquet before the clock starts (reading them is the floor's part)

With --ingest each round also times logiq_sql's whole ingest of the same Parquet (read, checks, kinematics,
keys, localisation, writing) and compares it with the sum of its own parts: floor (the read), window, write and
localisation, wall and CPU seconds. It also times one more part and gives the ratio with it as well:

    lanes write    the look-up's pairs written once into a DuckDB file, as the tracks are in ``write``: the
                   track_lanes rows of the first round's ingest, exported to Parquet before the clock starts and
                   written with one plain statement (benchmarks/README.md says why it is a part)

With --kept each round also times one more write, the rows a first match keeps for re-matches to read (issue 32's
step cache): needs a tiers run's file of the tier (benchmarks/work/<TIER>/bench.duckdb and its .step_cache):

    kept write     every table the file's step cache entries name (relations, lanes of the egos and actors, actor
                   paths, phases, frames), exported to Parquet before the clock starts and written once into a
                   DuckDB file, table after table, with one plain statement each; the relations table's own write
                   is given beside the total

The sum of these parts says how far any design of the pipeline could get: the issue-15 targets are 40x the floor
end to end (which holds every part) and 3 M rows/s re-matching (which holds the pair join, not the rest).
Written: benchmarks/results/<TIER>_components.json and .md.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import duckdb
import numpy as np
import polars as pl

from benchmarks.tiers import FLOOR_SQL, WORK, write_results
from logiq_sql.core.timing import cpu_seconds
from logiq_sql.ingestion.ingest import ingest
from logiq_sql.ingestion.localise import CHUNK_POINTS, STATIC_KINDS, LaneIndex
from logiq_sql.storage import step_cache

PARTS = {
    "floor": FLOOR_SQL,
    "window": """
        select sum(step_m) from (
            select x_m - lag(x_m) over (partition by drive_id, actor_id order by frame) as step_m
            from read_parquet($path)
        )""",
    "write": "create table tracks as select * from read_parquet($path)",
    "pair join": """
        with t as (
            select drive_id, actor_id, frame, x_m, y_m, cast(floor(x_m / 201.0) as bigint) as band
            from read_parquet($path)
        ),
        every_tenth as (
            select drive_id, actor_id from (
                select drive_id, actor_id, row_number() over (partition by drive_id order by actor_id) as n
                from (select distinct drive_id, actor_id from t))
            where n % 10 = 1
        ),
        egos as (
            select t.drive_id, t.actor_id, t.frame, t.x_m, t.y_m, t.band + n.d as band
            from t
            inner join every_tenth using (drive_id, actor_id)
            cross join (select -1 as d union all select 0 as d union all select 1 as d) as n
        )
        select count(*) from egos as e
        inner join t as a
            on e.drive_id = a.drive_id and e.frame = a.frame and e.band = a.band and e.actor_id <> a.actor_id
            and (a.x_m - e.x_m) * (a.x_m - e.x_m) + (a.y_m - e.y_m) * (a.y_m - e.y_m) <= 40000
        """,
}


def pair_count(index: LaneIndex, x: np.ndarray, y: np.ndarray, heading: np.ndarray) -> int:
    """How many (point, lane) pairs the look-up finds, chunk by chunk as ingest localises."""
    return sum(len(index.locate(x[a:a + CHUNK_POINTS], y[a:a + CHUNK_POINTS], heading[a:a + CHUNK_POINTS])[0])
               for a in range(0, len(x), CHUNK_POINTS))


def map_rows(path: Path) -> list[tuple[pl.DataFrame, np.ndarray, np.ndarray, np.ndarray]]:
    """Each map's lanes and the x, y and heading of its drives' moving rows (read before the clock starts)."""
    parquet = path.parent
    with duckdb.connect() as con:
        rows = con.sql("""
            select d.map_id, t.x_m, t.y_m, coalesce(t.heading_rad, 0) as heading_rad from read_parquet($tracks) as t
            inner join read_parquet($drives) as d on t.drive_id = d.drive_id
            where not list_contains($static_kinds, t.kind) order by d.map_id""",
            params={"tracks": str(path), "drives": str(parquet / "drives.parquet"),
                    "static_kinds": list(STATIC_KINDS)}).pl()
    lanes = pl.read_parquet(parquet / "lanes.parquet", columns=["map_id", "lane_id", "polygon_wkt", "centerline_wkt"])
    out = []
    for (map_id,), on_map in rows.partition_by("map_id", as_dict=True, maintain_order=True).items():
        on_lanes = lanes.filter(pl.col("map_id") == map_id)
        if not on_lanes.is_empty():
            out.append((on_lanes, *(on_map[c].to_numpy() for c in ("x_m", "y_m", "heading_rad"))))
    return out


def localisation(path: Path) -> int:
    """The (row, lane) pairs of the localisation part over the tier's Parquet."""
    return look_up(map_rows(path))


def look_up(maps: list) -> int:
    """The localisation part: every moving row's lanes, map by map (the index built per map: counted), the rows of
    a map split between two threads; the (row, lane) pairs counted."""
    total = 0
    with ThreadPoolExecutor(2) as pool:
        for lanes, x, y, h in maps:
            index = LaneIndex(lanes)
            half = len(x) // 2
            total += sum(pool.map(pair_count, [index, index], [x[:half], x[half:]], [y[:half], y[half:]],
                                  [h[:half], h[half:]]))
    return total


def timed(fn) -> tuple[float, float]:
    """Wall and CPU seconds (every thread of the process) of ``fn()``."""
    start, cpu = time.perf_counter(), cpu_seconds()
    fn()
    return time.perf_counter() - start, cpu_seconds() - cpu


def measure(path: Path, cpu: dict[str, float] | None = None) -> dict[str, float]:
    """Wall seconds of each part (and their CPU seconds into ``cpu``)."""
    seconds: dict[str, float] = {}
    cpu = {} if cpu is None else cpu
    for name, sql in PARTS.items():
        with tempfile.TemporaryDirectory() as tmp, duckdb.connect(str(Path(tmp) / "part.duckdb")) as con:
            seconds[name], cpu[name] = timed(lambda con=con, sql=sql: con.execute(sql, {"path": str(path)}).fetchall())
    maps = map_rows(path)
    seconds["localisation"], cpu["localisation"] = timed(lambda: look_up(maps))
    return seconds


# ingest's own parts: the read of the Parquet (the floor's scan), the window its kinematics need, the write of the
# tracks and the lane look-up
INGEST_PARTS = ("floor", "window", "write", "localisation")


# with it, the pairs the look-up finds are also written once, as ingest stores them for matching to read
WITH_LANES_WRITE = (*INGEST_PARTS, "lanes write")
LANES_WRITE = "create table track_lanes as select * from read_parquet($path)"
# the parts the end-to-end target counts (issue 33: the pipeline at most 4x their sum)
PIPELINE_PARTS = ("floor", "window", "write", "pair join", "localisation")
# writes timed besides the parts, given apart from their sum
MORE_WRITES = ("lanes write", "kept write", "relations write")
KEPT_WRITE = "create table kept_{i} as select * from read_parquet($path)"
RELATIONS_STEP = "relations relations/relations.sql"


def export_kept(tier_db: Path, out: Path) -> list[dict]:
    """The tables the step cache of ``tier_db`` keeps (those its entries name), each exported to ``out`` as Parquet
    (before the clock): the file, its rows and columns and the steps it holds rows of."""
    kept = []
    with duckdb.connect(str(step_cache.path_of(tier_db)), read_only=True) as con:
        for table, steps in con.execute("select table_name, string_agg(distinct step, ', ' order by step) "
                                        "from step_cache group by table_name order by table_name").fetchall():
            path = out / f"{table}.parquet"  # table names are step_cache_<hex key>, made by the cache itself
            con.execute(f"copy {table} to '{path}' (format parquet)")
            (rows,) = con.execute(f"select count(*) from {table}").fetchone()
            columns = len(con.execute(f"select * from {table} limit 0").description)
            kept.append({"path": path, "rows": rows, "columns": columns, "steps": steps})
    return kept


def write_kept(kept: list[dict], db: Path, cpu: dict[str, float]) -> dict[str, float]:
    """The kept write: each exported table written once into the new DuckDB file ``db`` (``kept_<i>``, in the order
    of ``kept``); wall seconds of the whole and of the relations table alone (their CPU seconds into ``cpu``)."""
    seconds = {"kept write": 0.0, "relations write": 0.0}
    cpu.update({"kept write": 0.0, "relations write": 0.0})
    with duckdb.connect(str(db)) as con:
        for i, table in enumerate(kept):
            wall, used = timed(lambda i=i, table=table: con.execute(KEPT_WRITE.format(i=i),
                                                                    {"path": str(table["path"])}).fetchall())
            for name in ("kept write", "relations write") if RELATIONS_STEP in table["steps"] else ("kept write",):
                seconds[name] += wall
                cpu[name] += used
    return seconds


def ingest_once(path: Path, lanes_out: Path | None = None) -> tuple[float, float]:
    """Wall and CPU seconds of logiq_sql's ingest of the tier's Parquet folder into a new file (with localisation);
    with ``lanes_out``, the file's track_lanes are then exported there (after the clock) for the lanes write."""
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "ingest.duckdb"
        seconds = timed(lambda: ingest("parquet", [path.parent], db))
        if lanes_out is not None:
            with duckdb.connect(str(db), read_only=True) as con:
                con.execute(f"copy track_lanes to '{lanes_out}' (format parquet)")
        return seconds


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", default="M")
    parser.add_argument("--ingest", action="store_true",
                        help="also time logiq_sql's ingest of the same Parquet in each round, against its parts")
    parser.add_argument("--kept", action="store_true",
                        help="also time writing the rows a first match keeps in the step cache (needs a tiers run's "
                             "file of the tier)")
    args = parser.parse_args(argv)
    path = WORK / args.tier / "parquet" / "tracks.parquet"
    if not path.exists():
        raise SystemExit(f"{path} not found: run `make bench TIER={args.tier}` first.")
    tier_db = WORK / args.tier / "bench.duckdb"
    if args.kept and not step_cache.path_of(tier_db).exists():
        raise SystemExit(f"{step_cache.path_of(tier_db)} not found: run `python -m benchmarks.tiers --tier "
                         f"{args.tier}` first (its first match keeps the steps).")
    rounds = []
    with tempfile.TemporaryDirectory(dir=WORK) as keep:
        lanes = Path(keep) / "track_lanes.parquet"
        kept = export_kept(tier_db, Path(keep)) if args.kept else []
        for _ in range(2):
            cpu: dict[str, float] = {}
            wall = {}
            if kept:
                with tempfile.TemporaryDirectory() as tmp:
                    wall |= write_kept(kept, Path(tmp) / "kept.duckdb", cpu)
            if args.ingest:
                wall["ingest"], cpu["ingest"] = ingest_once(path, None if lanes.exists() else lanes)
                with tempfile.TemporaryDirectory() as tmp, duckdb.connect(str(Path(tmp) / "part.duckdb")) as con:
                    wall["lanes write"], cpu["lanes write"] = timed(
                        lambda con=con: con.execute(LANES_WRITE, {"path": str(lanes)}).fetchall())
            wall |= measure(path, cpu)
            rounds.append((wall, cpu))
    # the faster of two rounds, as for the floor
    seconds = {k: min(r[0][k] for r in rounds) for k in rounds[0][0]}
    cpus = {k: min(r[1][k] for r in rounds) for k in rounds[0][1]}
    floor = seconds["floor"]
    parts = {k: {"seconds": v, "cpu_seconds": cpus[k], "ratio_to_floor": v / floor}
             for k, v in sorted(seconds.items(), key=lambda kv: kv[0] in MORE_WRITES) if k != "ingest"}
    report = {"tier": args.tier, "parts": parts,
              "sum_ratio_to_floor": sum(p["ratio_to_floor"] for k, p in parts.items()
                                        if k != "floor" and k not in MORE_WRITES),
              "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    lines = [f"# Tier {args.tier}: the pipeline's unavoidable parts alone", "",
             "| part | wall s | x floor | CPU s |", "|---|---:|---:|---:|"]
    lines += [f"| {k} | {p['seconds']:.2f} | {p['ratio_to_floor']:.1f} | {p['cpu_seconds']:.2f} |"
              for k, p in parts.items()]
    lines += ["", f"Sum of the parts other than the floor (and the writes after them): "
              f"**{report['sum_ratio_to_floor']:.1f}x the floor** "
              f"(measured {report['measured_at']})."]
    if args.ingest:
        rows = pl.scan_parquet(path).select(pl.len()).collect().item()
        own = {"seconds": sum(seconds[k] for k in INGEST_PARTS), "cpu_seconds": sum(cpus[k] for k in INGEST_PARTS)}
        more = {"seconds": sum(seconds[k] for k in WITH_LANES_WRITE),
                "cpu_seconds": sum(cpus[k] for k in WITH_LANES_WRITE)}
        report["ingest"] = {"seconds": seconds["ingest"], "cpu_seconds": cpus["ingest"], "rows": rows,
                            "rows_per_s": rows / seconds["ingest"], "parts": own,
                            "ratio_to_parts": seconds["ingest"] / own["seconds"],
                            "cpu_ratio_to_parts": cpus["ingest"] / own["cpu_seconds"],
                            "parts_with_lanes_write": more,
                            "ratio_to_parts_with_lanes_write": seconds["ingest"] / more["seconds"],
                            "cpu_ratio_to_parts_with_lanes_write": cpus["ingest"] / more["cpu_seconds"]}
        r = report["ingest"]
        lines += ["", f"**Ingest with localisation** (logiq_sql, the same Parquet, each round): {r['seconds']:.2f} s "
                  f"({r['rows_per_s']:,.0f} rows/s), CPU {r['cpu_seconds']:.2f} s; its parts "
                  f"({' + '.join(INGEST_PARTS)}) {own['seconds']:.2f} s, CPU {own['cpu_seconds']:.2f} s: **{r['ratio_to_parts']:.2f}x its parts** "
                  f"(CPU {r['cpu_ratio_to_parts']:.2f}x). With the lanes write among them "
                  f"({more['seconds']:.2f} s, CPU {more['cpu_seconds']:.2f} s): "
                  f"**{r['ratio_to_parts_with_lanes_write']:.2f}x** (CPU {r['cpu_ratio_to_parts_with_lanes_write']:.2f}x)."]
    if kept:
        budget = 4 * sum(seconds[k] for k in PIPELINE_PARTS)
        report["kept"] = {"tables": len(kept), "rows": sum(t["rows"] for t in kept),
                          "cells": sum(t["rows"] * t["columns"] for t in kept),
                          "relations_rows": sum(t["rows"] for t in kept if RELATIONS_STEP in t["steps"]),
                          "pipeline_budget_s": budget}
        k = report["kept"]
        lines += ["", f"**Kept write**: the {k['tables']} tables of the tier's step cache, {k['rows']:,} rows, "
                  f"{k['cells']:,} cells ({k['relations_rows']:,} rows of relations), written in "
                  f"{seconds['kept write']:.2f} s (CPU {cpus['kept write']:.2f} s), the relations alone "
                  f"{seconds['relations write']:.2f} s. The end-to-end target, 4x the parts "
                  f"({' + '.join(PIPELINE_PARTS)}), is {budget:.2f} s; the kept write is "
                  f"{seconds['kept write'] / budget:.0%} of it."]
        if args.ingest:
            k["left_for_match_s"] = budget - seconds["ingest"] - seconds["kept write"]
            lines[-1] += (f" After the ingest ({seconds['ingest']:.2f} s) and the kept write, "
                          f"{k['left_for_match_s']:.2f} s are left for computing everything a first match keeps.")
    write_results(f"{args.tier}_components", report, "\n".join(lines))
    return report


if __name__ == "__main__":
    main()
