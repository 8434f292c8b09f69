"""The KPI and sample queries of each scenario, as another git revision writes them against this checkout's (which
read the matched rows, queries/kpis/match_rows.sql), on the same matches of one ingested file, alternately:

    python -m benchmarks.kpi_rows --db benchmarks/work/S/bench.duckdb --base main --rounds 5

The relations (once, for every scenario) and each scenario's phases and matches are computed by this checkout (on
a copy of the file, with the default parameters), then
each round runs the base revision's KPI and sample query files and this checkout's (match_rows included), and
reads the CPU seconds of the process (all threads) around each. Prints the medians per scenario and in total,
and checks that both give the same rows (EXCEPT ALL both ways).
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from logiq_sql.core.sql import query_text, unit_constant
from logiq_sql.engines.duckdb_engine import DuckEngine
from logiq_sql.matching.match import select_run_drives
from logiq_sql.matching.runner import prepare_relations
from logiq_sql.spec.plan import (
    IDENTIFY_QUERY,
    MATCH_ROWS_STEP,
    SAMPLES_QUERY,
    parse_ego,
    phase_steps,
    resolve_scenarios,
    run_values,
)
from logiq_sql.storage import db

ROOT = Path(__file__).resolve().parent.parent


def bound(text: str, values: dict[str, object]) -> dict[str, object]:
    names = dict.fromkeys(re.findall(r"\$(\w+)", text))
    return {n: values[n] if n in values else unit_constant(n) for n in names}


def timed(con, queries: list[tuple[str, str]], values: dict[str, object]) -> float:
    """CPU seconds of running ``queries`` (table, text) in order, each kept as a temp table."""
    start = time.process_time()
    for table, text in queries:
        con.execute(f"create or replace temp table {table} as {text}", bound(text, values))
    return time.process_time() - start


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--db", type=Path, required=True, help="an ingested DuckDB file (copied, never changed)")
    parser.add_argument("--base", default="main", help="git revision whose KPI and sample queries to compare")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--ego", default="every:10")
    args = parser.parse_args(argv)

    def base_text(rel: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), "show", f"{args.base}:queries/{rel}"], check=True,
                              capture_output=True, text=True).stdout

    totals = {"base": 0.0, "this": 0.0}
    with tempfile.TemporaryDirectory(prefix="kpi_rows_") as tmp:
        copy = Path(tmp) / "copy.duckdb"
        shutil.copy(args.db, copy)
        con = db.connect(copy)
        con.register("run_drives", select_run_drives(con, None))
        engine = DuckEngine(con)
        scenarios = resolve_scenarios(None, {})
        prepare_relations(engine, scenarios, run_values(scenarios[0], parse_ego(args.ego), 200.0))
        for s in scenarios:
            values = run_values(s, parse_ego(args.ego), 200.0)
            for table, rel in phase_steps(s):
                engine.materialise(table, rel, values)
            engine.materialise("scenario_matches", IDENTIFY_QUERY, values)
            engine.materialise("match_samples", SAMPLES_QUERY, values)
            outputs = [(f"_kpi_{i}", rel) for i, rel in enumerate(s.kpi_queries)]
            outputs += [(f"_sample_{i}", rel) for i, rel in enumerate(s.sample_queries)]
            versions = {"base": [(f"base{t}", base_text(rel)) for t, rel in outputs],
                        "this": [(MATCH_ROWS_STEP[0], query_text(MATCH_ROWS_STEP[1])),
                                 *[(f"this{t}", query_text(rel)) for t, rel in outputs]]}
            cpu: dict[str, list[float]] = {name: [] for name in versions}
            for _ in range(args.rounds):
                for name, queries in versions.items():
                    cpu[name].append(timed(con, queries, values))
            differ = [rel for t, rel in outputs
                      if con.execute(f"select count(*) from ((select * from base{t} except all select * from this{t})"
                                     f" union all (select * from this{t} except all select * from base{t}))"
                                     ).fetchone()[0]]
            med = {name: statistics.median(c) for name, c in cpu.items()}
            for name in totals:
                totals[name] += med[name]
            matches = con.execute("select count(*) from scenario_matches").fetchone()[0]
            print(f"{s.name}: {matches} matches; median CPU s {args.base} {med['base']:.3f}, this {med['this']:.3f} "
                  f"({med['base'] / med['this']:.2f}x); same rows: {'yes' if not differ else 'no: ' + str(differ)}",
                  flush=True)
        con.close()
    print(f"all scenarios: median CPU s {args.base} {totals['base']:.3f}, this {totals['this']:.3f} "
          f"({totals['base'] / totals['this']:.2f}x) over {args.rounds} rounds")


if __name__ == "__main__":
    main()
