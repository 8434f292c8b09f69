"""Re-match one ingested file with two versions of the code, alternately, in one run: the CPU seconds of each
and their ratio (on a shared machine separate benchmark runs differ more than a change does).

    python -m benchmarks.rematch_ab --db benchmarks/work/S/bench.duckdb --base main --rounds 3

``--base`` is a git revision: its tree is extracted to a temporary folder and run with PYTHONPATH set to it;
the other version is this checkout. Each round runs ``match --force`` (every drive reruns) with each version
in a child process of its own, on copies of the file, and reads the child's CPU seconds (all threads) and wall
time around the call. The file must have been ingested by the newer version (an older one ignores the columns
it does not know). Prints the medians and base / this as the speed-up; checks both give the same matches.

``--set NAME=VALUE`` (repeatable): after its ``match --force``, each child also re-matches with that parameter
changed, as ``match --set`` does (the step cache holds what the forced run computed), and the same is reported
for that re-match (``param_cpu_s``, ``param_wall_s``; same matches checked too).

``--tiers-changes``: instead, the re-matches benchmarks/tiers.py times (its PARAM_CHANGE, then back to the
defaults, its DURATION_CHANGE, then back), each timed, on the file as it is (``--no-force``: no ``match --force``
first; use a file whose step cache holds the default run, e.g. a tier file after its benchmark).
``--first``: instead of ``match --force``, a first match: the file as ingested (give one with no step cache
beside it), so every step is computed and the cache written, as the pipeline's first match does.
``--prime``: before the rounds each version matches a copy of the file once with the defaults (not timed), so that
its step cache holds the default run in that version's own layout (a version whose cache is a file beside the
file, ``<file>.step_cache``, and one that keeps it inside compare fairly); each round starts from a copy of that.
"Same results" compares matches, match_phases and kpis (a digest of their rows, in order) after each re-match.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import tempfile
from pathlib import Path

from benchmarks.tiers import DURATION_CHANGE, PARAM_CHANGE
from benchmarks.versions import ROOT, checkout, run_child
from logiq_sql.storage.step_cache import path_of

CHILD = """
import json, resource, sys, time
import duckdb
from logiq_sql import match
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
def matches():
    with duckdb.connect(sys.argv[1], read_only=True) as con:
        return con.execute(
            "select (select md5(string_agg(m::varchar, ';' order by match_id)) "
            "from (select * exclude (run_id) from matches) as m) || "
            "(select md5(string_agg(p::varchar, ';' order by match_id, phase_index)) from match_phases as p) || "
            "(select md5(string_agg(k::varchar, ';' order by match_id)) from kpis as k)").fetchone()[0]
out = {}
# (prefix, force, overrides): the re-matches to time, in order
for prefix, force, overrides in json.loads(sys.argv[3]):
    start, c = time.perf_counter(), cpu()
    match(sys.argv[1], ego=sys.argv[2], force=force, overrides=overrides)
    out.update({prefix + "wall_s": time.perf_counter() - start, prefix + "cpu_s": cpu() - c,
                prefix + "matches": matches()})
print(json.dumps(out))
"""


def run(code: Path, db: Path, ego: str, plan: list[tuple[str, bool, dict[str, str]]]) -> dict[str, float]:
    return run_child(code, CHILD, str(db), ego, json.dumps(plan))


def _copy(db: Path, to: Path) -> Path:
    """The file ``db`` copied to ``to``, with its step cache file when it has one beside it."""
    shutil.copy(db, to)
    path_of(to).unlink(missing_ok=True)
    if path_of(db).is_file():
        shutil.copy(path_of(db), path_of(to))
    return to


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--db", type=Path, required=True, help="an ingested DuckDB file (copied, never changed)")
    parser.add_argument("--base", default="main", help="git revision to compare with (default main)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--ego", default="every:10")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="also time a re-match with this parameter changed, after each forced one")
    parser.add_argument("--tiers-changes", action="store_true",
                        help="time the re-matches of benchmarks/tiers.py (one parameter changed and back, twice)")
    parser.add_argument("--no-force", action="store_true", help="no match --force first")
    parser.add_argument("--first", action="store_true",
                        help="time a first match of the ingested file (no step cache) instead of match --force")
    parser.add_argument("--prime", action="store_true",
                        help="each version first matches its own copy with the defaults, untimed; rounds start there")
    args = parser.parse_args(argv)
    if args.set and args.tiers_changes:
        parser.error("--set or --tiers-changes, not both")
    changes = [("param_", dict(item.split("=", 1) for item in args.set))] if args.set else []
    if args.tiers_changes:
        changes = [("param_", PARAM_CHANGE[1]), ("param_back_", {}), ("duration_", DURATION_CHANGE[1]),
                   ("duration_back_", {})]
    if args.first and (args.no_force or args.prime or path_of(args.db).is_file()):
        parser.error("--first times a first match: a file with no step cache beside it, without --no-force or "
                     "--prime")
    plan = ([] if args.no_force else [("", not args.first, {})]) + [(prefix, False, o) for prefix, o in changes]
    labels = {"": "first match" if args.first else "match --force",
              **{prefix: f"re-match with {o or 'the defaults back'}" for prefix, o in changes}}
    with tempfile.TemporaryDirectory(prefix="rematch_ab_") as tmp:
        base = checkout(args.base, Path(tmp) / "base")
        versions = {args.base: base, "this": ROOT}
        times: dict[str, list[dict[str, float]]] = {name: [] for name in versions}
        start = {name: args.db for name in versions}
        for name, code in versions.items() if args.prime else ():
            start[name] = _copy(args.db, Path(tmp) / f"primed_{name.replace('/', '_')}.duckdb")
            print(f"primed {name}: {run(code, start[name], args.ego, [('', False, {})])}", flush=True)
        for i in range(args.rounds):
            for name, code in versions.items():
                copy = _copy(start[name], Path(tmp) / f"{name.replace('/', '_')}.duckdb")
                times[name].append(run(code, copy, args.ego, plan))
                print(f"round {i + 1} {name}: {times[name][-1]}", flush=True)
    for prefix in (p for p, _, _ in plan):
        label = labels[prefix]
        med = {name: {k: statistics.median(t[prefix + k] for t in runs) for k in ("cpu_s", "wall_s")}
               for name, runs in times.items()}
        same = len({t[prefix + "matches"] for runs in times.values() for t in runs}) == 1
        print(f"{label}:")
        for name, m in med.items():
            print(f"  {name}: median CPU {m['cpu_s']:.2f} s, wall {m['wall_s']:.2f} s over {args.rounds} runs")
        print(f"  speed-up (base / this): CPU {med[args.base]['cpu_s'] / med['this']['cpu_s']:.2f}x, "
              f"wall {med[args.base]['wall_s'] / med['this']['wall_s']:.2f}x; same matches: {same}")


if __name__ == "__main__":
    main()
