"""The scenario-independent stages (relations, junctions) of two versions of the code, alternately, in one run:
the CPU seconds of each step and stage, their ratio, and whether both versions' tables are the same rows.

    python -m benchmarks.relations_ab --db benchmarks/work/M/bench.duckdb --base main --rounds 3

``--base`` is a git revision: its tree is extracted to a temporary folder and run with PYTHONPATH set to it; the
other version is this checkout. Each round runs, in a child process per version, what ``match --force`` runs
before the phases: for every batch of drives (match's batches), ``runner.prepare_relations`` for the group of
every scenario, with the step cache off (what keeping the rows costs is the cache's, not the steps'). The child
reads its CPU seconds (all threads) around each step. The file is opened read-only and never changed.

With ``--compare`` (default on) the first round's children also write every table of the two stages to Parquet,
and the tables of the two versions are compared as multisets (EXCEPT ALL both ways, on the columns both have):
a speed change must leave every row as it was.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

from benchmarks.versions import ROOT, checkout, run_child

# what the stages write: the relation steps, then (junction scenarios) the junction steps and encroachments
TABLES = ("egos", "lane_line", "lane_neighbours", "actor_lanes", "ego_lanes", "relations",
          "actor_paths", "passages", "junction_frames", "crossing_pairs", "encroachments")

CHILD = """
import collections, json, os, sys
import polars as pl
from logiq_sql.core.sql import registered
from logiq_sql.core.timing import cpu_seconds, recording
from logiq_sql.engines import open_engine
from logiq_sql.matching.match import match_batches, select_run_drives
from logiq_sql.matching.runner import prepare_relations
from logiq_sql.spec.plan import parse_ego, relation_range_m, relation_settings, resolve_scenarios, run_values
from logiq_sql.storage import db

path, ego, dump, tables = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
chosen = resolve_scenarios(None, {})
assert len({relation_settings(s) for s in chosen}) == 1, "every scenario in one relation group"
values = run_values(chosen[0], parse_ego(ego), relation_range_m("200m"))
steps = collections.Counter()
con = db.connect(path, read_only=True)
runner = open_engine("duckdb", con, None, None, None)
for name in ("materialise", "derive"):
    def timed(table, *args, _inner=getattr(runner, name), **kwargs):
        start = cpu_seconds()
        _inner(table, *args, **kwargs)
        steps[table] += cpu_seconds() - start
    setattr(runner, name, timed)
drives = select_run_drives(con, None)["drive_id"].to_list()
with recording() as rec:
    for i, batch in enumerate(match_batches(con, tuple(drives), 2_000_000)):
        todo = pl.DataFrame({"drive_id": batch}, schema={"drive_id": pl.String})
        with registered(con, "run_drives", todo):
            runner.select_drives()
            prepare_relations(runner, chosen, values)
            if dump:
                for table in tables:
                    out = f"{dump}/{table}"
                    os.makedirs(out, exist_ok=True)
                    con.execute(f"copy (select * from {table}) to '{out}/{i}.parquet' (format parquet)")
            runner.release_drives()
print(json.dumps({"stages": rec.cpu_seconds, "steps": dict(steps)}))
"""


def run(code: Path, db: Path, ego: str, dump: str) -> dict[str, dict[str, float]]:
    return run_child(code, CHILD, str(db), ego, dump, json.dumps(TABLES))


def differences(a: Path, b: Path) -> dict[str, str]:
    """Per table: 'same (N rows)' or what differs between the two dumps (EXCEPT ALL both ways)."""
    import duckdb

    con = duckdb.connect(config={"memory_limit": "2GB", "temp_directory": str(a.parent / "spill")})
    out = {}
    for table in TABLES:
        if not (a / table).exists() or not (b / table).exists():
            out[table] = "missing in " + ("base" if not (a / table).exists() else "this")
            continue
        left, right = f"read_parquet('{a / table}/*.parquet')", f"read_parquet('{b / table}/*.parquet')"
        cols_a = [r[0] for r in con.execute(f"describe select * from {left}").fetchall()]
        cols_b = [r[0] for r in con.execute(f"describe select * from {right}").fetchall()]
        shared = ", ".join(f'"{c}"' for c in cols_a if c in cols_b)
        only = sorted(set(cols_a) ^ set(cols_b))
        (n,) = con.execute(f"select count(*) from {left}").fetchone()
        (ab,) = con.execute(f"select count(*) from (select {shared} from {left} except all "
                            f"select {shared} from {right})").fetchone()
        (ba,) = con.execute(f"select count(*) from (select {shared} from {right} except all "
                            f"select {shared} from {left})").fetchone()
        out[table] = (f"same ({n:,} rows)" if ab == ba == 0 else f"DIFFERENT: {ab} rows only in base, {ba} only in this"
                      ) + (f"; columns in one only: {only}" if only else "")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for flag, default, text in (("--base", "main", "git revision to compare with (default main)"),
                                ("--ego", "every:10", "SUT choice, as match --ego (default every:10)")):
        parser.add_argument(flag, default=default, help=text)
    parser.add_argument("--db", type=Path, required=True, help="an ingested DuckDB file (opened read-only)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, each running both versions (default 3)")
    parser.add_argument("--no-compare", action="store_true", help="skip the comparison of the tables")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="relations_ab_") as tmp:
        base = checkout(args.base, Path(tmp) / "base")
        versions = {args.base: base, "this": ROOT}
        runs: dict[str, list[dict[str, dict[str, float]]]] = {name: [] for name in versions}
        for i in range(args.rounds):
            for name, code in versions.items():
                dump = "" if args.no_compare or i else str(Path(tmp) / "dump" / name.replace("/", "_"))
                runs[name].append(run(code, args.db, args.ego, dump))
                print(f"round {i + 1} {name}: " + ", ".join(f"{k} {v:.2f}" for k, v in runs[name][-1]["stages"].items())
                      + " CPU s", flush=True)
        print(f"\nmedian CPU s of {args.rounds} rounds (all threads), {args.db}, ego {args.ego}:")
        print(f"| step | {args.base} | this | ratio |\n|---|---:|---:|---:|")
        for kind in ("steps", "stages"):
            names = dict.fromkeys(n for r in runs.values() for one in r for n in one[kind])
            for step in names:
                med = [statistics.median(one[kind].get(step, 0.0) for one in runs[v]) for v in versions]
                ratio = f"{med[0] / med[1]:.2f}x" if med[1] else "-"
                label = f"**{step}**" if kind == "stages" else step
                print(f"| {label} | {med[0]:.2f} | {med[1]:.2f} | {ratio} |")
        if not args.no_compare:
            print("\ntables (EXCEPT ALL both ways):")
            for table, verdict in differences(*(Path(tmp) / "dump" / n.replace("/", "_") for n in versions)).items():
                print(f"  {table}: {verdict}")


if __name__ == "__main__":
    main()
