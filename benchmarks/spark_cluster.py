"""The cost of scale: a tier from Parquet to Parquet on a Spark standalone cluster, beside DuckDB, in one run.

    python -m benchmarks.spark_cluster --tier S                 # 1 worker, then 2 workers (one core each)
    python -m benchmarks.spark_cluster --tier M --workers 2
    python -m benchmarks.spark_cluster --tier S --rows 200000   # try the harness on fewer rows

The tier's replicated Parquet (benchmarks/tiers.py) is, in this order:
1. ingested into a DuckDB file and matched there (every scenario, ``--ego every:10``): the reference;
2. ingested into a dataset (``ingest parquet ... --dataset``; on a fleet many machines do this file by file);
3. matched on a standalone cluster of N workers (benchmarks/cluster.py: master and workers as their own JVMs from
   PySpark's ``bin/spark-class``, one core and ``--worker-memory`` each, the wheel shipped to the executors), from
   the dataset to Parquet written by the executors (``match --engine spark --dataset DIR --out OUT``), once per
   N in ``--workers``.
Each Spark run's matches, phases and KPIs are compared with DuckDB's (floats within 1e-9 relative). Reported: wall
time, this process's CPU time (the driver; the executors are other processes), rows per second, and rows per
second per executor core. Written: benchmarks/results/<TIER>_spark.json and .md.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import shutil
import time

from benchmarks.cluster import project_zip, session, standalone
from benchmarks.tiers import RESULTS, TIERS, WORK, outputs_against, prepare
from logiq_sql.core.timing import cpu_seconds
from logiq_sql.ingestion.dataset_ingest import ingest_dataset
from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.match import match, match_dataset


def timed(run) -> tuple[float, float]:
    start, cpu = time.perf_counter(), cpu_seconds()
    run()
    return time.perf_counter() - start, cpu_seconds() - cpu


def load() -> float:
    with open("/proc/loadavg") as f:
        return float(f.read().split()[0])


def markdown(r: dict) -> str:
    n = r["rows"]
    lines = [f"# Tier {r['tier']} on a Spark standalone cluster: {n:,} track rows, ego {r['ego']}", "",
             f"Measured {r['measured_at']} on {r['machine']}; load average at the start {r['load_at_start']:.1f}. "
             f"Workers: one core and {r['worker_memory']} each; executors {r['executor_memory']}.", "",
             "| run | wall s | driver CPU s | rows/s | rows/s per executor core | load after | outputs vs DuckDB |",
             "|---|---:|---:|---:|---:|---:|---|"]
    d = r["duckdb"]
    lines.append(f"| DuckDB: ingest + match (one process, 2 threads) | {d['seconds']:.1f} | {d['cpu_seconds']:.1f} | "
                 f"{n / d['seconds']:,.0f} | - | {d['load_after']:.1f} | reference |")
    i = r["dataset_ingest"]
    lines.append(f"| ingest --dataset (one process) | {i['seconds']:.1f} | {i['cpu_seconds']:.1f} | "
                 f"{n / i['seconds']:,.0f} | - | {i['load_after']:.1f} | - |")
    for s in r["spark"]:
        lines.append(f"| Spark match, {s['workers']} worker(s), dataset -> Parquet | {s['seconds']:.1f} | "
                     f"{s['cpu_seconds']:.1f} | {n / s['seconds']:,.0f} | {n / s['seconds'] / s['workers']:,.0f} | "
                     f"{s['load_after']:.1f} | " + ", ".join(f"{k} {v}" for k, v in s["outputs"].items()) + " |")
    lines += ["", f"DuckDB's match alone: {r['duckdb']['match_seconds']:.1f} s "
              f"({n / r['duckdb']['match_seconds']:,.0f} rows/s)."]
    for s in r["spark"]:
        lines.append(f"Spark with {s['workers']} worker(s): {s['seconds'] / r['duckdb']['match_seconds']:.2f}x "
                     "DuckDB's match time.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", choices=list(TIERS), default="S")
    parser.add_argument("--rows", type=int, help="override the tier's row count (for trying the harness)")
    parser.add_argument("--ego", default="every:10", help="SUT choice (see match --ego; default every:10)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="cluster sizes to run (default 1 2)")
    parser.add_argument("--worker-memory", default="3g", help="memory of each worker (default 3g)")
    parser.add_argument("--executor-memory", default="2g", help="heap of each executor (default 2g)")
    args = parser.parse_args(argv)
    rows = args.rows or TIERS[args.tier]
    work = WORK / f"{args.tier}_spark"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    with multiprocessing.get_context("spawn").Pool(1) as pool:  # the input, prepared in a child process
        n, _sources = pool.apply(prepare, (rows, work / "parquet"))
    report: dict = {"tier": args.tier, "rows": n, "ego": args.ego, "load_at_start": load(),
                    "worker_memory": args.worker_memory, "executor_memory": args.executor_memory,
                    "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                    "machine": f"{platform.machine()}, {multiprocessing.cpu_count()} cores, "
                               f"Python {platform.python_version()}", "spark": []}

    reference = work / "duckdb.duckdb"
    ingest_s, ingest_cpu = timed(lambda: ingest("parquet", [work / "parquet"], reference))
    match_s, match_cpu = timed(lambda: match(reference, ego=args.ego))
    report["duckdb"] = {"seconds": ingest_s + match_s, "cpu_seconds": ingest_cpu + match_cpu,
                        "match_seconds": match_s, "load_after": load()}
    dataset = work / "dataset"
    seconds, cpu = timed(lambda: ingest_dataset("parquet", [work / "parquet"], dataset))
    report["dataset_ingest"] = {"seconds": seconds, "cpu_seconds": cpu, "load_after": load()}

    shipped = project_zip(work / "dist")
    for workers in args.workers:
        out = work / f"out_{workers}"
        with standalone(work / f"cluster_{workers}", workers, memory=args.worker_memory) as (url, _):
            spark = session(url, shipped, workers, executor_memory=args.executor_memory, driver_memory="4g")
            try:
                seconds, cpu = timed(lambda: match_dataset(dataset, out, ego=args.ego, engine="spark",
                                                           spark_master=url))
            finally:
                spark.stop()
        report["spark"].append({"workers": workers, "seconds": seconds, "cpu_seconds": cpu, "load_after": load(),
                                "outputs": outputs_against(reference, out / "logiq.duckdb")})
        print(f"{workers} worker(s): {seconds:.1f} s")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.tier}_spark.json").write_text(json.dumps(report, indent=2))
    (RESULTS / f"{args.tier}_spark.md").write_text(markdown(report))
    print(markdown(report))
    return report


if __name__ == "__main__":
    main()
