"""One query file against its text at an earlier commit, on a tier's ingested file: the same rows, and the time.

    python -m benchmarks.queries --tier S --against d51a17b phases/follower_vehicle.sql relations/ego_lanes.sql

For speed work on a single query: the tier's file (written by ``python -m benchmarks.tiers --tier S``; or
``--db``) is opened read-only, the shared steps (egos, the relation steps, the junction steps and the encroachment
areas) are computed with the current files, with the values of the first scenario that runs each query (``--ego
every:10``, as the tiers), and the scenario's frames step when a phase reads it; then each query's current text and
its text at ``--against`` run alternately ``--repeat`` times on the same connection, and their outputs are compared
with EXCEPT ALL both ways (every column, every row, duplicates counted). Prints the best wall time and the best CPU
seconds (the process's, every DuckDB thread) of each and whether the rows are the same; nothing is written.
``--holding`` also times each phase query as a match runs it (only its rows where it holds).
"""

from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path

import duckdb

from benchmarks.tiers import WORK
from logiq_sql.core.sql import bind, materialise, query_text
from logiq_sql.matching.encroachment import encroachments
from logiq_sql.spec.plan import JUNCTION_STEPS, RELATION_STEPS, parse_ego, resolve_scenarios, run_values, scenario_steps


def text_at(revision: str, relative: str) -> str:
    return subprocess.run(["git", "show", f"{revision}:queries/{relative}"], capture_output=True, text=True,
                          check=True).stdout


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("queries", nargs="+", metavar="QUERY", help="query files relative to queries/")
    parser.add_argument("--tier", default="S")
    parser.add_argument("--against", required=True, metavar="REV", help="the git revision to compare with")
    parser.add_argument("--ego", default="every:10")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--db", type=Path, help="an ingested file (default the tier's)")
    parser.add_argument("--holding", action="store_true", help="time phase queries as a match runs them too")
    parser.add_argument("--memory-limit", help="DuckDB's memory_limit (e.g. 2GB: the steps' rows spill to disk)")
    args = parser.parse_args(argv)
    scenarios = resolve_scenarios(None, {})
    values = {s.name: run_values(s, parse_ego(args.ego), 200.0) for s in scenarios}
    con = duckdb.connect(str(args.db or WORK / args.tier / "bench.duckdb"), read_only=True)
    con.execute("set enable_progress_bar = false")
    if args.memory_limit:
        con.execute("set memory_limit = $limit", {"limit": args.memory_limit})
    con.execute("create temp table run_drives as select drive_id from drive_inputs where status = 'ingested'")
    shared = values[scenarios[0].name]
    for table, rel in (("egos", "relations/egos.sql"), *RELATION_STEPS, *JUNCTION_STEPS):
        materialise(con, table, rel, shared)
    con.register("_encroachments", encroachments(con))
    con.execute("create or replace temp table encroachments as select * from _encroachments")
    threads = con.execute("select current_setting('threads')").fetchall()[0][0]
    rows = []
    for rel in args.queries:
        owner = next(s for s in scenarios if rel in (r for _, r in scenario_steps(s))) if rel.startswith("phases/") \
            else scenarios[0]
        if owner.frames_query and rel != owner.frames_query:  # the phases of a scenario with a frames step read it
            materialise(con, "scenario_frames", owner.frames_query, values[owner.name])
        for holding in (False, True) if args.holding and rel.startswith("phases/") and rel != owner.frames_query \
                else (False,):
            rows.append(compare(con, rel, bind(rel, values[owner.name]), args.against, args.repeat, holding, threads))
    return rows


def compare(con: duckdb.DuckDBPyConnection, rel: str, bound: dict[str, object], against: str, repeat: int,
            holding: bool, threads: int) -> dict[str, object]:
    """One query's current text and its text at ``against``, alternately: best wall and CPU seconds, same rows."""
    texts = {"now": query_text(rel), against: text_at(against, rel)}
    if holding:
        texts = {name: f"select * from (\n{text}\n) as step where holds" for name, text in texts.items()}
    best = {name: float("inf") for name in texts}
    best_cpu = dict(best)
    con.execute(f"set threads = {threads}")  # as a run executes it
    for _ in range(repeat):
        for name, text in texts.items():
            start, cpu = time.perf_counter(), time.process_time()
            con.execute(f"create or replace temp table _{abs(hash(name))} as {text}", bound)
            best[name] = min(best[name], time.perf_counter() - start)
            best_cpu[name] = min(best_cpu[name], time.process_time() - cpu)
    a, b = (f"_{abs(hash(name))}" for name in texts)
    differ = sum(con.execute(f"select count(*) from (select * from {x} except all select * from {y})")
                 .fetchall()[0][0] for x, y in ((a, b), (b, a)))
    n = con.execute(f"select count(*) from {a}").fetchall()[0][0]
    for table in (a, b):  # a tier-M phase's rows take gigabytes
        con.execute(f"drop table {table}")
    shown = rel + (" (rows where it holds)" if holding else "")
    print(f"{shown}: {n:,} rows; now {best['now']:.3f} s ({best_cpu['now']:.2f} CPU s), at {against} "
          f"{best[against]:.3f} s ({best_cpu[against]:.2f} CPU s); CPU {best_cpu[against] / best_cpu['now']:.2f}x; "
          + ("same rows" if differ == 0 else f"{differ} rows DIFFER"))
    return {"query": rel, "holding": holding, "rows": n, "now_s": best["now"], "before_s": best[against],
            "now_cpu_s": best_cpu["now"], "before_cpu_s": best_cpu[against], "differ": differ}


if __name__ == "__main__":
    main()
