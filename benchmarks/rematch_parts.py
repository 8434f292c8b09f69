"""Where one re-match goes: wall and CPU seconds (all threads) of each part of a ``match`` run on a file, one run.

    python -m benchmarks.rematch_parts --db COPY.duckdb --change param     # tiers.PARAM_CHANGE
    python -m benchmarks.rematch_parts --db COPY.duckdb --change duration  # tiers.DURATION_CHANGE
    python -m benchmarks.rematch_parts --db COPY.duckdb --change back      # every parameter at its default
    python -m benchmarks.rematch_parts --db COPY.duckdb --change force     # match --force

The file is re-matched (pass a copy, with its step cache `<file>.step_cache` copied beside it). Parts are the
functions of the run wrapped with a timer: the file's working copy and its publishing, selecting a batch's drives,
each step the engine computes (by query file), the step cache's look-ups and writes, storing a batch's results. Parts
nest (a scenario's run holds its steps), so they do not add up to the whole; a part called once per batch is summed
over the batches.
"""

from __future__ import annotations

import argparse
import collections
import functools
import time
from pathlib import Path

from benchmarks.tiers import DURATION_CHANGE, PARAM_CHANGE
from logiq_sql.core.timing import cpu_seconds
from logiq_sql.engines import duckdb_engine
from logiq_sql.matching import match as matching
from logiq_sql.storage import db, step_cache, store

PARTS: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0, 0])  # name -> wall, CPU, calls


def _timed(function, name):
    @functools.wraps(function)
    def timed(*args, **kwargs):
        part = name(*args, **kwargs) if callable(name) else name
        wall, cpu = time.perf_counter(), cpu_seconds()
        try:
            return function(*args, **kwargs)
        finally:
            seen = PARTS[part]
            seen[0] += time.perf_counter() - wall
            seen[1] += cpu_seconds() - cpu
            seen[2] += 1
    return timed


def _wrap(owner, attribute: str, name) -> None:
    setattr(owner, attribute, _timed(getattr(owner, attribute), name))


def instrument() -> None:
    engine, cache = duckdb_engine.DuckEngine, step_cache.StepCache
    for owner, attribute, name in (
            (db.Writer, "_prepare", "file: working copy"), (db.Writer, "publish", "file: publish"),
            (engine, "select_drives", "engine: select a batch's drives"),
            (engine, "release_drives", "engine: release a batch's drives"),
            (engine, "_compute", lambda self, table, relative, *a, **k: f"compute {relative}"),
            (engine, "frame", "engine: frames read"),
            (cache, "start_batch", "cache: batch's entries"), (cache, "load", "cache: read a step"),
            (cache, "record", "cache: record a step"), (cache, "_point_entries", "cache: write entries and rows"),
            (matching, "store_batch", "store a batch's results"), (matching, "read_result", "read the results"),
            (matching, "drives_to_match", "drives to match"), (store, "recount_coverage", "store: coverage"),
            (matching, "run_scenario", lambda engine, s, values: f"scenario {s.name}"),
            (matching, "prepare_relations", "relations and junctions")):
        _wrap(owner, attribute, name)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--db", type=Path, required=True, help="an ingested and matched DuckDB file (re-matched)")
    parser.add_argument("--change", choices=("param", "duration", "back", "force"), default="param")
    parser.add_argument("--ego", default="every:10")
    args = parser.parse_args(argv)
    overrides = {"param": PARAM_CHANGE[1], "duration": DURATION_CHANGE[1]}.get(args.change, {})
    instrument()
    wall, cpu = time.perf_counter(), cpu_seconds()
    result = matching.match(args.db, ego=args.ego, overrides=overrides, force=args.change == "force")
    wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
    print(f"match {args.change} {overrides}: wall {wall:.2f} s, CPU {cpu:.2f} s; {result.cache}")
    print("| part | calls | wall s | CPU s |\n|---|---:|---:|---:|")
    for name, (w, c, n) in sorted(PARTS.items(), key=lambda kv: -kv[1][1]):
        if c >= 0.05 or w >= 0.1:
            print(f"| {name} | {n} | {w:.2f} | {c:.2f} |")


if __name__ == "__main__":
    main()
