"""Ingest one tier's Parquet with two versions of the code, alternately, in one run: the wall and CPU seconds and
the peak memory of each (on a shared machine separate benchmark runs differ more than a change does).

    python -m benchmarks.ingest_ab --tier L --base main --rounds 2

``--base`` is a git revision, extracted to a temporary folder (benchmarks/versions.py); the other version is this
checkout. Each round ingests benchmarks/work/<TIER>/parquet into a new file with the base, then with this
checkout, each in a child process of its own that reports its wall seconds, CPU seconds (all threads) and peak
resident memory. Results are printed, one line per ingest, and the medians; nothing is written. That two
versions store the same rows is checked by the tests and by comparing two ingested files (EXCEPT ALL both ways).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from benchmarks.tiers import WORK
from benchmarks.versions import ROOT, checkout, run_child

CHILD = """
import json, resource, sys, tempfile, time
from pathlib import Path
from logiq_sql.core.timing import cpu_seconds
from logiq_sql.ingestion.ingest import ingest
with tempfile.TemporaryDirectory() as tmp:
    start, cpu = time.perf_counter(), cpu_seconds()
    ingest("parquet", [sys.argv[1]], Path(tmp) / "ingest.duckdb")
    print(json.dumps({"wall_s": time.perf_counter() - start, "cpu_s": cpu_seconds() - cpu,
                      "peak_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}))
"""


def main(argv: list[str] | None = None) -> dict[str, list[dict]]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", default="M")
    parser.add_argument("--base", required=True, help="the git revision to compare this checkout with")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    parquet = WORK / args.tier / "parquet"
    if not (parquet / "tracks.parquet").exists():
        raise SystemExit(f"{parquet} not found: run `make bench TIER={args.tier}` first.")
    runs: dict[str, list[dict]] = {args.base: [], "this checkout": []}
    with tempfile.TemporaryDirectory() as tmp:
        trees = {args.base: checkout(args.base, Path(tmp) / "base"), "this checkout": ROOT}
        for i in range(args.rounds):
            for name, tree in trees.items():
                r = run_child(tree, CHILD, str(parquet))
                runs[name].append(r)
                print(f"round {i} {name}: wall {r['wall_s']:.2f} s, CPU {r['cpu_s']:.2f} s, "
                      f"peak {r['peak_gib']:.2f} GiB", flush=True)
    for name, rs in runs.items():
        print(f"median {name}: wall {statistics.median(r['wall_s'] for r in rs):.2f} s, "
              f"CPU {statistics.median(r['cpu_s'] for r in rs):.2f} s")
    return runs


if __name__ == "__main__":
    main()
