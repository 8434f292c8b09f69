"""Spine benchmark: ingest + match on the bundled real drives replicated to N track rows.

    python -m benchmarks.spine [--rows 10000000] [--ego every:10] [--json FILE]

1. Ingest the bundled real data (tests/data: NGSIM via CommonRoad, nuScenes via ScenarioNet) and export its
   canonical tables as Parquet.
2. Replicate the drives until the tracks reach --rows: copy k gets drive ids suffixed ``~k`` and times shifted by
   k hours (maps are shared, as a fleet driving the same roads would).
3. Time, in this one run: ingesting the replicated Parquet (derivations + shapely localisation), matching every
   scenario, and the floor: a plain DuckDB scan and group-by over the same track columns.

Printed: rows/s of each stage and the ratio of each to the floor. Machines are shared and noisy: compare ratios
measured in one run, never absolute times across runs.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import resource
import shutil
import time
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql import schema
from logiq_sql.db import memory_limit
from logiq_sql.ingestion import ingest
from logiq_sql.match import match

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
WORK = ROOT / "benchmarks" / "work"
FLOOR_SQL = """
select drive_id, actor_id, count(*), min(t_s), max(t_s), avg(x_m), avg(y_m), avg(speed_mps), max(accel_mps2)
from read_parquet($path)
group by drive_id, actor_id
"""


def timed(fn):
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def base_tables(work: Path) -> dict[str, pl.DataFrame]:
    db = work / "base.duckdb"
    ingest("commonroad", [DATA / "commonroad_ngsim"], db)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet"], db)
    with duckdb.connect(str(db), read_only=True) as con:
        return {t: con.sql(f"select * from {t}").pl() for t in
                ("tracks", "drive_inputs", "lanes", "lane_successors", "junctions", "traffic_lights",
                 "traffic_light_states")}


def replicate(tables: dict[str, pl.DataFrame], rows: int, out: Path) -> int:
    tracks = tables["tracks"].select("drive_id", "actor_id", "kind", "is_ego", "t_s", "x_m", "y_m",
                                     "heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m")
    copies = -(-rows // tracks.height)
    out.mkdir(parents=True, exist_ok=True)
    pl.concat([
        tracks.with_columns(pl.col("drive_id") + f"~{k}", pl.col("t_s") + 3600.0 * k) for k in range(copies)
    ]).write_parquet(out / "tracks.parquet", row_group_size=500_000)
    drives = tables["drive_inputs"].filter(pl.col("status") == "ingested").select(
        "drive_id", "dt_s", "map_id", "ego_actor_id", "attribution")
    pl.concat([drives.with_columns(pl.col("drive_id") + f"~{k}") for k in range(copies)]).write_parquet(
        out / "drives.parquet")
    for t in schema.MAP_TABLE_NAMES:
        tables[t].write_parquet(out / f"{t}.parquet")
    return copies * tracks.height


def prepare(rows: int) -> int:
    return replicate(base_tables(WORK), rows, WORK / "replicated")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, default=10_000_000, help="track rows after replication")
    parser.add_argument("--ego", default="every:10", help="SUT choice for ego-less NGSIM drives (see match --ego)")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "spine.json")
    args = parser.parse_args()

    shutil.rmtree(WORK, ignore_errors=True)
    WORK.mkdir(parents=True)
    # the input is prepared in a child process, so the peak memory below is the pipeline's own
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        n = pool.apply(prepare, (args.rows,))
    path = str(WORK / "replicated" / "tracks.parquet")

    floor_s, _ = timed(lambda: duckdb.connect().execute(FLOOR_SQL, {"path": path}).fetchall())
    db = WORK / "bench.duckdb"
    ingest_s, summary = timed(lambda: ingest("parquet", [WORK / "replicated"], db))
    match_s, result = timed(lambda: match(db, ego=args.ego))
    floor2_s, _ = timed(lambda: duckdb.connect().execute(FLOOR_SQL, {"path": path}).fetchall())
    floor_s = min(floor_s, floor2_s)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

    report = {
        "rows": n, "drives": summary.drives, "matches": result.matches.height, "ego": args.ego,
        "floor_s": floor_s, "ingest_s": ingest_s, "match_s": match_s, "pipeline_s": ingest_s + match_s,
        "ingest_rows_per_s": n / ingest_s, "match_rows_per_s": n / match_s,
        "pipeline_rows_per_s": n / (ingest_s + match_s), "floor_rows_per_s": n / floor_s,
        "ratio_to_floor": (ingest_s + match_s) / floor_s, "ingest_ratio_to_floor": ingest_s / floor_s,
        "match_ratio_to_floor": match_s / floor_s, "peak_rss_bytes": peak,
        "duckdb_memory_limit": memory_limit(),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2))
    print(f"track rows          {n:>14,}   ({summary.drives:,} drives, {result.matches.height:,} matches, ego {args.ego})")
    print(f"floor (scan+group)  {floor_s:>10.2f} s  {n / floor_s:>14,.0f} rows/s   1.0x")
    for name, secs in (("ingest", ingest_s), ("match", match_s), ("pipeline", ingest_s + match_s)):
        print(f"{name:<19} {secs:>10.2f} s  {n / secs:>14,.0f} rows/s   {secs / floor_s:,.1f}x floor")
    print(f"peak RSS            {peak / 2**30:>10.2f} GiB   (DuckDB memory_limit {memory_limit()})")
    print(f"written to {args.json}")


if __name__ == "__main__":
    main()
