"""One query file against its text at an earlier commit, on a tier's ingested file: the same rows, and the time.

    python -m benchmarks.queries --tier S --against d51a17b phases/follower_vehicle.sql relations/ego_lanes.sql

For speed work on a single query: the tier's file (written by ``python -m benchmarks.tiers --tier S``) is opened
read-only, the shared steps (egos, the relation steps, the junction steps) are computed with the current files,
with the values of the first scenario that runs each query (``--ego every:10``, as the tiers); then each query's
current text and its text at ``--against`` run alternately ``--repeat`` times on the same connection, and their
outputs are compared with EXCEPT ALL both ways (every column, every row, duplicates counted). Prints the best wall
time of each and whether the rows are the same; nothing is written.
"""

from __future__ import annotations

import argparse
import subprocess
import time

import duckdb

from benchmarks.tiers import WORK
from logiq_sql.core.sql import SINGLE_THREADED, bind, materialise, query_text
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
    args = parser.parse_args(argv)
    scenarios = resolve_scenarios(None, {})
    values = {s.name: run_values(s, parse_ego(args.ego), 200.0) for s in scenarios}
    con = duckdb.connect(str(WORK / args.tier / "bench.duckdb"), read_only=True)
    con.execute("create temp table run_drives as select drive_id from drive_inputs where status = 'ingested'")
    shared = values[scenarios[0].name]
    for table, rel in (("egos", "relations/egos.sql"), *RELATION_STEPS, *JUNCTION_STEPS):
        materialise(con, table, rel, shared)
    threads = con.execute("select current_setting('threads')").fetchall()[0][0]
    rows = []
    for rel in args.queries:
        owner = next(s for s in scenarios if rel in (r for _, r in scenario_steps(s))) if rel.startswith("phases/") \
            else scenarios[0]
        bound = bind(rel, values[owner.name])
        texts = {"now": query_text(rel), args.against: text_at(args.against, rel)}
        best = dict.fromkeys(texts, float("inf"))
        con.execute(f"set threads = {1 if rel in SINGLE_THREADED else threads}")  # as a run executes it
        for _ in range(args.repeat):
            for name, text in texts.items():
                start = time.perf_counter()
                con.execute(f"create or replace temp table _{abs(hash(name))} as {text}", bound)
                best[name] = min(best[name], time.perf_counter() - start)
        a, b = (f"_{abs(hash(name))}" for name in texts)
        differ = sum(con.execute(f"select count(*) from (select * from {x} except all select * from {y})")
                     .fetchall()[0][0] for x, y in ((a, b), (b, a)))
        n = con.execute(f"select count(*) from {a}").fetchall()[0][0]
        rows.append({"query": rel, "rows": n, "now_s": best["now"], "before_s": best[args.against], "differ": differ})
        print(f"{rel}: {n:,} rows; now {best['now']:.3f} s, at {args.against} {best[args.against]:.3f} s "
              f"({best[args.against] / best['now']:.2f}x); "
              + ("same rows" if differ == 0 else f"{differ} rows DIFFER"))
    return rows


if __name__ == "__main__":
    main()
