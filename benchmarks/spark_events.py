"""Where a Spark run's time went, from its event log (``spark.eventLog.enabled``; benchmarks/spark_cluster.py keeps
one per run under its work folder):

    python -m benchmarks.spark_events benchmarks/work/S_spark/events_2_1

Per job description (the Spark engine names each job after the step it computes or the table it writes;
otherwise the SQL execution's call site): jobs, tasks, the jobs' wall seconds, the executors' run and CPU seconds,
the bytes shuffled and spilled. The time between jobs is the driver's (analysing and planning the next statement,
Python). Sorted by executor run time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
from collections import defaultdict
from pathlib import Path


def lines(log: Path) -> list[str]:
    """The event log's lines (a .zstd one through the zstd tool)."""
    if log.suffix == ".zstd":
        return subprocess.run(["zstd", "-dcq", str(log)], check=True, capture_output=True, text=True).stdout.splitlines()
    return log.read_text().splitlines()


def summary(log: Path) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    """Per description: jobs, tasks, wall_s, run_s, cpu_s, shuffle_mb, spill_mb; and the run's totals."""
    sql_description: dict[int, str] = {}
    job_description: dict[int, str] = {}
    job_start: dict[int, float] = {}
    stage_job: dict[int, int] = {}
    rows: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    first = last = None
    for line in lines(log):
        try:
            e = json.loads(line)
        except json.JSONDecodeError:  # the last line of a log still being written
            continue
        kind = e["Event"]
        if kind.endswith("SparkListenerSQLExecutionStart"):
            sql_description[e["executionId"]] = e.get("description", "")
        elif kind == "SparkListenerJobStart":
            props = e.get("Properties") or {}
            what = props.get("spark.job.description") or sql_description.get(
                int(props.get("spark.sql.execution.id", -1)), "") or "(other)"
            job_description[e["Job ID"]] = what
            job_start[e["Job ID"]] = e["Submission Time"] / 1000
            for stage in e["Stage IDs"]:
                stage_job[stage] = e["Job ID"]
            rows[what]["jobs"] += 1
            first = first if first is not None else e["Submission Time"] / 1000
        elif kind == "SparkListenerJobEnd":
            what = job_description[e["Job ID"]]
            rows[what]["wall_s"] += e["Completion Time"] / 1000 - job_start[e["Job ID"]]
            last = e["Completion Time"] / 1000
        elif kind == "SparkListenerTaskEnd" and e.get("Task Metrics"):
            what = job_description.get(stage_job.get(e["Stage ID"], -1), "(other)")
            m = e["Task Metrics"]
            row = rows[what]
            row["tasks"] += 1
            row["run_s"] += m["Executor Run Time"] / 1000
            row["cpu_s"] += m["Executor CPU Time"] / 1e9
            row["shuffle_mb"] += m.get("Shuffle Write Metrics", {}).get("Shuffle Bytes Written", 0) / 2**20
            row["spill_mb"] += m.get("Disk Bytes Spilled", 0) / 2**20
    totals = {k: sum(r[k] for r in rows.values()) for k in ("jobs", "tasks", "wall_s", "run_s", "cpu_s", "shuffle_mb")}
    totals["span_s"] = (last or 0) - (first or 0)
    return rows, totals


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="the event log folder (or one log file)")
    parser.add_argument("--top", type=int, default=40)
    args = parser.parse_args(argv)
    logs = [args.folder] if args.folder.is_file() else sorted(
        p for p in args.folder.rglob("*") if p.is_file() and not p.name.startswith((".", "appstatus")))
    for log in logs:
        rows, totals = summary(log)
        print(f"{log.name}: {totals['jobs']:.0f} jobs, {totals['tasks']:.0f} tasks; first job to last "
              f"{totals['span_s']:.1f} s, in jobs {totals['wall_s']:.1f} s; executors run {totals['run_s']:.1f} s, "
              f"CPU {totals['cpu_s']:.1f} s; shuffled {totals['shuffle_mb']:.0f} MiB")
        print(f"{'description':60} {'jobs':>5} {'tasks':>6} {'wall s':>7} {'run s':>7} {'cpu s':>7} {'shuf MiB':>8}")
        for what, r in sorted(rows.items(), key=lambda kv: -kv[1]["run_s"])[:args.top]:
            print(f"{what[:60]:60} {r['jobs']:5.0f} {r['tasks']:6.0f} {r['wall_s']:7.1f} {r['run_s']:7.1f} "
                  f"{r['cpu_s']:7.1f} {r['shuffle_mb']:8.1f}")


if __name__ == "__main__":
    main()
