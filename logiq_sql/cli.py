"""The ``logiq-sql`` command: one function per command (``cmd_*``) and one per command's options (``add_*``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from importlib.metadata import version
from pathlib import Path

from logiq_sql.errors import DiskFullError, FileBusyError, LogiqError
from logiq_sql.plan import DEFAULT_RELATION_RANGE

# exit codes a scheduler can act on
EXIT_OK = 0  # done (also when the reader of the output closed the pipe early, as `| head` does)
EXIT_UNEXPECTED = 1  # a bug or an environment failure: the traceback says where
EXIT_BAD_INPUT = 2  # nothing was done: the message names the file, key or column and the fix
EXIT_REJECTED = 3  # ingest finished, but some drives were rejected (their reasons are in the drives table)
EXIT_BUSY = 4  # nothing was done: another run is writing the file (the message names it); retry or --wait
EXIT_DISK_FULL = 5  # the disk filled up: the run stopped, the file is as the last completed run left it
EPILOG = ("Docs: README.md and docs/ in the repository. Exit codes: 0 done, 1 unexpected failure, 2 bad input, "
          "3 ingest done but some drives rejected, 4 another run is writing the file, 5 disk full.")
DB_ENV = "LOGIQ_SQL_DB"  # the default of --db on every command that takes one
# how the CLI spells the Python arguments that library errors name (logiq_sql.errors.arg)
FLAGS = {"overrides": "--set", "drives": "--drive", "db_path": "--db", "name": "NAME", "wait_s": "--wait"}
QUERY_FORMATS = ("table", "csv", "json", "markdown")
TABLE_ROWS = 40  # rows `query --format table` prints unless --limit says otherwise


def _set_pairs(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise LogiqError(f"--set {item}: write NAME=VALUE with a unit, e.g. --set max_distance_from_cyclist=4m.")
        out[name.strip()] = value.strip()
    return out


def _say(quiet: bool):
    return None if quiet else (lambda msg: print(msg, file=sys.stderr))


def _db(args: argparse.Namespace) -> str:
    """--db, else $LOGIQ_SQL_DB."""
    db = args.db or os.environ.get(DB_ENV)
    if not db:
        raise LogiqError(f"{args.command}: no DuckDB file given: pass --db FILE or set {DB_ENV}=FILE.")
    return db


def cmd_ingest(args: argparse.Namespace) -> int:
    from logiq_sql.ingestion import ingest

    if args.db is not None and args.dataset is not None:
        raise LogiqError("ingest: give either --db FILE (a DuckDB file) or --dataset DIR (Parquet, docs/engines.md).")
    if args.dataset is not None:
        from logiq_sql.dataset_ingest import ingest_dataset

        summary = ingest_dataset(args.format, args.paths, args.dataset, progress=_say(args.quiet))
        print(f"{args.dataset}: {summary}")
        if summary.rejected:
            print(f"{summary.rejected} drive(s) rejected, each with its reason in {args.dataset}/drive_inputs "
                  "(status = 'rejected', reject_reason)")
            return EXIT_REJECTED
        return EXIT_OK
    db = _db(args)
    summary = ingest(args.format, args.paths, db, progress=_say(args.quiet), wait_s=args.wait)
    print(f"{db}: {summary}")
    if summary.rejected:
        print(f"{summary.rejected} drive(s) rejected, each with its reason: logiq-sql query --db {db} "
              "\"select drive_id, source_path, reject_reason from drives where status = 'rejected'\"")
        return EXIT_REJECTED
    return EXIT_OK


def cmd_simulate(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.perceive import Noise
    from logiq_sql.evaluation.simulate import Regime, simulate

    regime = Regime(lane_change_duration_s=args.lane_change_duration, truck_share=args.truck_share,
                    bus_share=args.bus_share, approach_lanes=args.approach_lanes, demand=args.demand,
                    creep=args.creep)
    noise = Noise(position_m=args.noise_position, heading_deg=args.noise_heading, speed_mps=args.noise_speed,
                  drop_share=args.noise_drop, seed=args.seed if args.noise_seed is None else args.noise_seed)
    if noise != Noise(seed=noise.seed) and not args.perceived:
        raise LogiqError("--noise-*: the noise goes into a perceived copy of the run, never into SUMO's own records. "
                         "Fix: add --perceived DIR (the copy is written to DIR/<run folder name>).")
    print(simulate(args.kind, args.minutes, args.seed, args.out, regime=regime, noise=noise,
                   perceived=args.perceived))
    if args.perceived:
        print(f"perceived copy ({noise}): {Path(args.perceived) / Path(args.out).name}")
    return EXIT_OK


def cmd_label(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.labels import label_runs

    labels = label_runs(args.runs, args.scenario or None, _set_pairs(args.set))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    labels.write_parquet(out)
    counts = labels.group_by("drive_id", "scenario").len().sort("drive_id", "scenario")
    for r in counts.iter_rows(named=True):
        print(f"  {r['drive_id']}: {r['scenario']}: {r['len']} label(s)", file=sys.stderr)
    print(f"{out}: {labels.height} label(s) of {labels['drive_id'].n_unique()} run(s)")
    return EXIT_OK


def cmd_evaluate(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.evaluate import evaluate

    result = evaluate(_db(args), args.labels, iou_threshold=args.iou, out=args.out)
    print(result.summary())
    if args.out:
        print(f"Parquet written to {Path(args.out).resolve()}")
    return EXIT_OK


def cmd_match(args: argparse.Namespace) -> int:
    from logiq_sql.match import match, match_dataset

    if args.dataset is not None and not args.out:
        raise LogiqError("match --dataset DIR: give --out DIR too (the results file is then OUT/logiq.duckdb).")
    common = dict(scenarios=args.scenario or None, ego=args.ego, overrides=_set_pairs(args.set),
                  drives=args.drive or None, relation_range=args.relation_range, progress=_say(args.quiet),
                  force=args.force, engine=args.engine, spark_master=args.spark_master, wait_s=args.wait,
                  scenario_path=args.scenario_path, ego_kinds=args.ego_kinds, keep=args.keep)
    if args.dataset is not None:  # with --engine spark, Spark writes the results itself under --out
        result = match_dataset(args.dataset, args.out, args.db, spark_tables=args.spark_tables or args.dataset,
                               **common)
    else:
        result = match(_db(args), out=args.out, spark_tables=args.spark_tables, **common)
    print(result.summary())
    if args.out:
        print(f"Parquet written to {Path(args.out).resolve()}")
    return EXIT_OK


def cmd_scenarios(args: argparse.Namespace) -> int:
    from logiq_sql.scenario import list_scenarios

    found = list_scenarios(args.scenario_path, include_abstract=args.all)
    if args.format == "json":
        print(json.dumps([{
            "name": s.name, "abstract": s.abstract, "extends": list(s.lineage[1:]), "description": s.description,
            "params": [{"name": p.name, "type": p.type, "default": p.text, "description": p.description,
                        "declared_in": p.declared_in} for p in s.params.values()],
            "phases": [ph.name for ph in s.phases], "kpis": [k.name for k in s.kpis],
            "coverage": [c.name for c in s.coverage]} for s in found], indent=2))
        return EXIT_OK
    for s in found:
        kind = "base scenario" if s.abstract else "scenario"
        print(f"{s.name}  ({kind}; extends {' -> '.join(s.lineage[1:]) or 'nothing'})")
        print(f"    {s.description}")
        for p in s.params.values():
            default = p.text if p.text is not None else "(no default)"
            print(f"    --set {p.name}=...  {p.type}, default {default}  [{p.declared_in}]")
            if p.description:
                print(f"        {p.description}")
        if not s.abstract:
            print(f"    phases: {', '.join(ph.name for ph in s.phases)}")
        print(f"    KPIs: {', '.join(k.name for k in s.kpis)}")
        print(f"    coverage: {', '.join(c.name for c in s.coverage)}")
        print()
    return EXIT_OK


def cmd_render(args: argparse.Namespace) -> int:
    from logiq_sql.match import render

    print(render(args.scenario, overrides=_set_pairs(args.set), ego=args.ego, relation_range=args.relation_range,
                 engine=args.engine, scenario_path=args.scenario_path, ego_kinds=args.ego_kinds))
    return EXIT_OK


def cmd_explain(args: argparse.Namespace) -> int:
    from logiq_sql.explain import explain

    result = explain(_db(args), args.scenario, args.drive, args.ego, actor=args.actor,
                     overrides=_set_pairs(args.set), relation_range=args.relation_range,
                     scenario_path=args.scenario_path, ego_kinds=args.ego_kinds)
    print(result.text())
    return EXIT_OK


def cmd_lint(args: argparse.Namespace) -> int:
    from logiq_sql.lint import lint_scenarios

    problems = lint_scenarios(args.scenario or None, args.scenario_path)
    for problem in problems:
        print(problem, file=sys.stderr)
    if problems:
        print(f"logiq-sql lint: {len(problems)} problem(s); the scenario contract is in docs/scenarios.md",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    print("scenarios and their SQL agree: " + (", ".join(args.scenario) if args.scenario else "every scenario"))
    return EXIT_OK


def _existing_db(args: argparse.Namespace) -> str:
    db = _db(args)
    if not Path(db).is_file():
        raise LogiqError(f"--db {db}: no such file (write one with `logiq-sql ingest`).")
    return db


def cmd_query(args: argparse.Namespace) -> int:
    import duckdb
    import polars as pl

    from logiq_sql.db import open_for_read

    db = _existing_db(args)
    if args.limit is not None and args.limit < 0:
        raise LogiqError(f"--limit {args.limit}: give a number of rows >= 0 (0: every row).")
    with open_for_read(db) as con:
        try:
            frame = con.sql(args.sql).pl()
        except duckdb.Error as exc:  # the analyst's SQL: a bad-input error, not a crash
            raise LogiqError(f"{exc}\n\nHint: the tables and their columns are in docs/tables.md.") from None
    limit = args.limit if args.limit is not None else (TABLE_ROWS if args.format == "table" else 0)
    shown = frame.head(limit) if limit else frame
    if args.format == "csv":
        sys.stdout.write(shown.write_csv())
    elif args.format == "json":
        print(json.dumps(shown.to_dicts(), default=str, indent=1))
    else:  # table or markdown: every digit of a float, as CSV and JSON give it
        with pl.Config(tbl_rows=-1, tbl_cols=-1, fmt_str_lengths=60, tbl_width_chars=200, fmt_float="full",
                       tbl_hide_dataframe_shape=True, tbl_hide_column_data_types=args.format == "markdown",
                       tbl_formatting="MARKDOWN" if args.format == "markdown" else None):
            print(shown)
    if shown.height < frame.height:
        print(f"logiq-sql: {shown.height} of {frame.height} rows shown (--limit N for more, --limit 0 for all)",
              file=sys.stderr)
    return EXIT_OK


def cmd_info(args: argparse.Namespace) -> int:
    from logiq_sql.db import open_for_read

    db = _db(args)
    with open_for_read(db) as con:
        tables = {r[0] for r in con.execute("select table_name from duckdb_tables()").fetchall()}
        if "drive_inputs" not in tables:
            raise LogiqError(f"--db {db}: not a logiq_sql file (no drive_inputs table).")
        drives = con.execute("select source_format, status, count(*) from drives group by all order by all").fetchall()
        tracks = con.execute("select count(*) from tracks").fetchone()[0]
        runs = con.execute("select count(distinct run_id), min(started_at), max(started_at) from match_runs").fetchone()
        per = con.execute(
            "select d.scenario, count(*) filter (where d.status = 'matched'), count(*), sum(d.matches)::bigint "
            "from drive_scenarios d group by 1 order by 1").fetchall()
    print(f"{db}: {sum(n for *_, n in drives)} drive(s), {tracks:,} track rows")
    for source in dict.fromkeys(source for source, *_ in drives):
        counts = [(status, n) for s, status, n in drives if s == source]
        print(f"  {source}: {sum(n for _, n in counts)} ({', '.join(f'{status} {n}' for status, n in counts)})")
    if not runs[0]:
        print(f"match runs: none yet (logiq-sql match --db {db})")
        return EXIT_OK
    print(f"match runs: {runs[0]} ({runs[1]} to {runs[2]})")
    for scenario, matched, total, matches in per:
        print(f"  {scenario}: {matches} match(es) in {matched} of {total} drive(s)")
    return EXIT_OK


def cmd_new_scenario(args: argparse.Namespace) -> int:
    from logiq_sql.scaffold import new_scenario

    for path in new_scenario(args.name, args.extends, args.dir):
        print(f"wrote {path}")
    print(f"next: logiq-sql lint {args.name} --scenario-path {args.dir}; then logiq-sql match --scenario-path "
          f"{args.dir} --scenario {args.name} (the contract: docs/scenarios.md)")
    return EXIT_OK


def cmd_cache(args: argparse.Namespace) -> int:
    from logiq_sql import step_cache
    from logiq_sql.db import open_for_read, open_for_write

    db = _existing_db(args)
    if args.clear:
        with open_for_write(db) as con:
            step_cache.clear(con)
    with open_for_read(db) as con:
        print(f"step cache of {db}: {step_cache.describe(step_cache.size(con))}")
    return EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from logiq_sql.report import report

    print(f"report written to {report(_db(args), args.out).resolve()}")
    return EXIT_OK


def cmd_replay(args: argparse.Namespace) -> int:
    from logiq_sql.replay import save

    print(f"replay of {args.match_id} written to {save(_db(args), args.match_id, args.out, args.step).resolve()}")
    return EXIT_OK


def cmd_export_xosc(args: argparse.Namespace) -> int:
    from logiq_sql.export.xosc import export_xosc

    done = export_xosc(_db(args), args.match_id, args.out, convert_map=args.convert_map)
    vertices = ", ".join(f"{who} {n}" for who, n in done.vertices.items())
    print(f"OpenSCENARIO written to {done.path.resolve()} (trajectory vertices: {vertices}; {done.map_reference})")
    return EXIT_OK


def cmd_export_openlabel(args: argparse.Namespace) -> int:
    from logiq_sql.export.openlabel import export_openlabel

    files = export_openlabel(_db(args), args.out, drives=args.drive or None)
    print(f"{len(files)} OpenLABEL file(s) written to {Path(args.out).resolve()}")
    return EXIT_OK


# --- options shared by several commands ------------------------------------------------------------------------------

def _add_db(p: argparse.ArgumentParser, what: str = "DuckDB file written by ingest and match") -> None:
    p.add_argument("--db", metavar="FILE", help=f"{what} (default: ${DB_ENV})")


def _add_wait(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wait", type=float, default=0.0, metavar="SECONDS",
                   help="when another run is writing the file, wait up to this long for it (a progress line every "
                        "10 s) instead of stopping at once with exit code 4 (default 0)")


def _add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", action="store_true", help="no progress lines (the summary and exit code stay)")


def _add_set(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override a parameter, with its unit (e.g. max_distance_from_cyclist=4m)")


def _add_relation_range(p: argparse.ArgumentParser) -> None:
    p.add_argument("--relation-range", default=DEFAULT_RELATION_RANGE, metavar="LENGTH",
                   help="keep ego-actor pairs whose centres are at most this far apart "
                        f"(default {DEFAULT_RELATION_RANGE}: a 5 s headway at 140 km/h)")


def _add_scenario_path(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario-path", metavar="DIR",
                   help="a folder of your own scenario files (and their SQL), besides the built-in ones; they may "
                        "extend the built-in bases (docs/scenarios.md)")


def _add_ego_kinds(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ego-kinds", metavar="KINDS",
                   help="the kinds that can be the SUT for --ego auto, all and every:N, comma-separated (default "
                        "vehicle,truck,bus,motorcycle,emergency_vehicle; car means vehicle)")


def _command(sub, name: str, func, help: str, description: str | None = None,
             hidden: bool = False) -> argparse.ArgumentParser:
    """A command's parser; a ``hidden`` one is left out of the command list (argparse lists only those with help)."""
    listed = {} if hidden else {"help": help}
    p = sub.add_parser(name, description=description or help[0].upper() + help[1:] + ".", epilog=EPILOG, **listed)
    p.set_defaults(func=func, renamed=f"eval {name}" if hidden else None)
    return p


# --- one function per command -----------------------------------------------------------------------------------------

def add_ingest(sub) -> None:
    p = _command(sub, "ingest", cmd_ingest, "read drives into a DuckDB file",
                 "Read drives (files or folders of them) into the canonical tables of a DuckDB file. Re-ingesting a "
                 "drive replaces it.")
    p.add_argument("format", choices=["commonroad", "scenarionet", "parquet", "sumo", "av2", "opendrive", "osi"],
                   help="commonroad: CommonRoad XML (.xml, .xml.gz); scenarionet: ScenarioNet .pkl; "
                        "parquet: canonical tables (see docs/tables.md); sumo: SUMO run folders (docs/sumo.md); "
                        "av2: Argoverse 2 sensor-log and motion-forecasting folders; opendrive: an .xodr map with "
                        "tracks.parquet beside it; osi: ASAM OSI traces (.osi, .mcap), with an .xodr beside them "
                        "as the map (docs/formats.md)")
    p.add_argument("paths", nargs="+", metavar="PATH", help="files or folders")
    _add_db(p, "DuckDB file to create or update")
    p.add_argument("--dataset", metavar="DIR", help="instead of --db: write the canonical tables as Parquet "
                   "partitioned by drive into DIR, file by file, so many machines can ingest into one DIR "
                   "(docs/engines.md)")
    _add_quiet(p)
    _add_wait(p)


def add_match(sub) -> None:
    p = _command(sub, "match", cmd_match, "match scenarios against the drives of a DuckDB file",
                 "Match scenarios and store matches, match_phases, kpis and coverage in the file.")
    _add_db(p, "DuckDB file written by ingest (with --dataset: the results file, default OUT/logiq.duckdb)")
    p.add_argument("--dataset", metavar="DIR", help="match the Parquet dataset written by ingest --dataset; --db "
                   "then gets views over it beside the results (docs/engines.md)")
    p.add_argument("--scenario", action="append", metavar="NAME", help="scenario to match (repeatable; default all)")
    p.add_argument("--ego", default="auto", metavar="auto|recorded|all|every:N|IDS",
                   help="who is the SUT: auto (recorded ego, else every actor of an ego kind: car, truck, bus, ...; "
                        "default), recorded, all (every actor of an ego kind), every:N, or actor ids, comma-separated")
    _add_ego_kinds(p)
    _add_scenario_path(p)
    _add_set(p)
    p.add_argument("--drive", action="append", metavar="ID", help="only these drives (repeatable)")
    _add_relation_range(p)
    p.add_argument("--out", metavar="DIR", help="also write the output tables as Parquet into DIR")
    p.add_argument("--keep", action="store_true",
                   help="also store the intermediate tables relations, passages and encroachments for analysts "
                        "(ego_lanes is always stored); without it they are recomputed on demand (explain, "
                        "relations_of). The kept relations holds only the actor kinds some scenario of the run "
                        "can use (every kind unless all of them declare relation_kinds, e.g. the cyclist "
                        "scenario alone: cyclists only); relations_of(drive_id, ego_id) gives the full relation")
    p.add_argument("--force", action="store_true",
                   help="rerun drives already matched with the same scenario version, parameters, ego and range "
                        "(skipped by default)")
    _add_quiet(p)
    p.add_argument("--engine", choices=["duckdb", "spark", "polars"], default="duckdb",
                   help="what runs the queries: duckdb (default), spark (pip install 'logiq-sql[spark]', Java 17) "
                        "or polars (Polars SQL, with its overrides: docs/engines.md). Results land "
                        "in --db either way")
    p.add_argument("--spark-master", metavar="URL",
                   help="Spark master for --engine spark (default: $SPARK_MASTER, else local[2])")
    p.add_argument("--spark-tables", metavar="DIR",
                   help="where --engine spark writes the canonical tables as Parquet (partitioned by drive_id) for "
                        "Spark to read; on a cluster, a folder every executor can read (default: a temporary folder)")
    _add_wait(p)


def add_scenarios(sub) -> None:
    p = _command(sub, "scenarios", cmd_scenarios, "list scenarios with their parameters, defaults and descriptions")
    p.add_argument("--all", action="store_true", help="include the base scenarios")
    p.add_argument("--format", choices=["table", "json"], default="table",
                   help="table (default) or json: a list of scenarios, each with its parameters (name, type, "
                        "default, description, declared_in), phases, KPIs and coverage items")
    _add_scenario_path(p)


def add_lint(sub) -> None:
    p = _command(sub, "lint", cmd_lint, "check scenarios against their SQL, before any data is read",
                 "Load each scenario (every key of every table, with did-you-mean), check the parameters each SQL "
                 "file uses, the columns each phase, KPI and sample query returns against what the scenario "
                 "declares, and the SQL's portability. Problems name the file and key; exit 2 when there is any.")
    p.add_argument("scenario", nargs="*", metavar="SCENARIO", help="scenarios to check (default: all)")
    _add_scenario_path(p)


def add_new_scenario(sub) -> None:
    p = _command(sub, "new-scenario", cmd_new_scenario, "start a scenario of your own: a TOML file and its SQL",
                 "Write DIR/NAME.toml and DIR/NAME.sql: a one-phase scenario extending BASE (a follower at most "
                 "max_time_headway behind the Ego, in its lane) that passes `lint` and matches as written; edit "
                 "both from there (docs/scenarios.md, the phase contract).")
    p.add_argument("name", metavar="NAME", help="the scenario's name: lower case, digits and _")
    p.add_argument("--extends", default="logiq_base_lane_following_scenario", metavar="BASE",
                   help="the base scenario to extend (default logiq_base_lane_following_scenario; "
                        "`logiq-sql scenarios --all` lists them)")
    p.add_argument("--dir", default="scenarios", metavar="DIR",
                   help="folder to write into (default ./scenarios); pass it as --scenario-path to the other commands")


def add_render(sub) -> None:
    p = _command(sub, "render", cmd_render, "print the SQL that matches a scenario, with its parameters set",
                 "Print one statement that finds the scenario's matches: SET VARIABLE lines bind the parameters, "
                 "then the query files as CTEs. Runs as-is in DuckDB against a file written by ingest. With "
                 "--engine spark: the same steps in Spark SQL, the parameter values listed as comments, to bind "
                 "with spark.sql(text, args=...).")
    p.add_argument("scenario", metavar="SCENARIO")
    _add_set(p)
    p.add_argument("--ego", default="auto", help="as for match")
    _add_ego_kinds(p)
    _add_scenario_path(p)
    _add_relation_range(p)
    p.add_argument("--engine", choices=["duckdb", "spark"], default="duckdb",
                   help="duckdb (default): SET VARIABLE lines and the statement; spark: the Spark SQL statement with "
                        "the values to bind (spark.sql(text, args=...)) listed as comments above it")


def add_explain(sub) -> None:
    p = _command(sub, "explain", cmd_explain,
                 "why a scenario did not match: the first phase and condition that failed",
                 "Rerun a scenario's steps for one drive and ego (read-only) and print, for each actor its first "
                 "phase considers, how many phases it got through and, where it stopped, the conditions of the next "
                 "phase that failed, with the measured values, and where a gap or a flicker of at most max_gap was "
                 "bridged. Every scenario.")
    _add_db(p, "DuckDB file written by ingest")
    p.add_argument("--scenario", required=True, metavar="NAME")
    p.add_argument("--drive", required=True, metavar="ID")
    p.add_argument("--ego", required=True, metavar="IDS", help="the ego's actor id(s), comma-separated, or recorded")
    p.add_argument("--actor", metavar="ID", help="only this actor")
    _add_ego_kinds(p)
    _add_scenario_path(p)
    _add_set(p)
    _add_relation_range(p)


def add_query(sub) -> None:
    p = _command(sub, "query", cmd_query, "run read-only SQL against a DuckDB file and print the rows",
                 "Run read-only SQL against the file (as the last completed run published it) and print the rows, "
                 "floats with every digit. A write or a bad query is exit 2. Tables: docs/tables.md.")
    p.add_argument("sql", metavar="SQL")
    _add_db(p)
    p.add_argument("--format", choices=QUERY_FORMATS, default="table",
                   help="table (default), csv, json (a list of rows) or markdown")
    p.add_argument("--limit", type=int, metavar="N",
                   help=f"print at most N rows, 0 for all (default: {TABLE_ROWS} for table, all for the others); "
                        "when rows are left out, stderr says how many")


def add_info(sub) -> None:
    p = _command(sub, "info", cmd_info, "say what a file holds: drives by source and status, runs, matches",
                 "What a logiq_sql file holds: its drives by source format and status, track rows, the match runs, "
                 "and per scenario the matches and the drives matched.")
    _add_db(p)


def add_cache(sub) -> None:
    p = _command(sub, "cache", cmd_cache, "the size of the step cache in a DuckDB file, or --clear it",
                 "match keeps the rows of its steps in the file and reads them back when a later run needs the same "
                 "step (same SQL, values and drive rows): docs/operations.md, 'The step cache'. Re-ingesting a drive "
                 "drops its entries; --clear drops all.")
    _add_db(p)
    p.add_argument("--clear", action="store_true", help="drop every entry of the cache")


def add_report(sub) -> None:
    p = _command(sub, "report", cmd_report, "write one self-contained HTML report of a matched file",
                 "Coverage histograms, KPI distributions, the match table with filters, every drive's status and "
                 "the runs with their parameters, in one HTML file with inline SVG charts (no network needed to "
                 "view it).")
    _add_db(p)
    p.add_argument("--out", required=True, metavar="FILE", help="HTML file to write, e.g. report.html")


def add_replay(sub) -> None:
    p = _command(sub, "replay", cmd_replay, "write the animated bird's-eye replay of one match as a GIF or an MP4",
                 "The replay the report shows (lanes, junctions, the ego and the actor as boxes, the phases on a "
                 "timeline, gap, headway, TTC and speeds), as a GIF (Pillow) or an MP4 (ffmpeg from "
                 "imageio-ffmpeg). match_id: the matches table's first column.")
    p.add_argument("match_id", metavar="MATCH_ID")
    _add_db(p)
    p.add_argument("--out", required=True, metavar="FILE", help="file to write: .gif or .mp4")
    p.add_argument("--step", type=int, default=None, metavar="N",
                   help="draw every N-th frame (default: at most 150 frames)")


def add_export(sub) -> None:
    p = sub.add_parser("export", help="write a match as OpenSCENARIO or the drives' matches as OpenLABEL",
                       epilog=EPILOG, description="Export into standard formats (mappings: docs/formats.md).")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="FORMAT")
    x = _command(kinds, "xosc", cmd_export_xosc,
                 "one match as an OpenSCENARIO 1.3 file: ego and actor replay their tracks")
    x.add_argument("match_id", metavar="MATCH_ID", help="matches.match_id")
    _add_db(x)
    x.add_argument("--out", required=True, metavar="FILE", help="the .xosc file to write")
    x.add_argument("--convert-map", action="store_true",
                   help="for a drive on a SUMO network (still in its run folder): write the network as OpenDRIVE "
                        "beside the .xosc with netconvert (the [sumo] extra) and reference it")
    o = _command(kinds, "openlabel", cmd_export_openlabel,
                 "one ASAM OpenLABEL 1.0 JSON file per drive: tags, objects, phases, KPIs")
    _add_db(o)
    o.add_argument("--out", required=True, metavar="DIR", help="folder to write {drive_id}.json into")
    o.add_argument("--drive", action="append", metavar="ID", help="only these drives (repeatable; default all "
                                                                   "ingested drives)")


def add_eval(sub) -> None:
    """``logiq-sql eval simulate|label|evaluate``: the evaluation harness (logiq_sql.evaluation), apart from the
    product's commands."""
    p = sub.add_parser("eval", help="the evaluation harness: simulate drives with SUMO, label them from SUMO's "
                       "records, score matches (docs/evaluation.md)", epilog=EPILOG,
                       description="The evaluation harness: how well the matcher finds what a simulator knows "
                                   "happened (docs/evaluation.md, docs/sumo.md).")
    _add_harness(p.add_subparsers(dest="harness", required=True, metavar="COMMAND"))
    _add_harness(sub, hidden=True)  # the old top-level names, still parsed; `_run` says where they went


def _add_harness(harness, hidden: bool = False) -> None:
    s = _command(harness, "simulate", cmd_simulate, "simulate drives with Eclipse SUMO (optional extra [sumo])",
                 "Build a motorway or a signalised junction with SUMO's own tools and run it at 0.1 s steps; writes "
                 "the network, routes, FCD and SUMO's reference outputs into DIR, ready for `ingest sumo DIR` "
                 "(docs/sumo.md). Needs pip install 'logiq-sql[sumo]'.", hidden)
    s.add_argument("kind", choices=["motorway", "junction"],
                   help="motorway: 3.5 km, 3 lanes, on- and off-ramp, dense mixed traffic; junction: signalised "
                        "4-way junction with permissive left turns, cars and bicycles")
    s.add_argument("--minutes", type=float, default=5.0, help="simulated minutes (default 5; the first 60 s "
                                                              "are warm-up)")
    s.add_argument("--seed", type=int, default=1, help="random seed (default 1); the same seed gives the same run")
    s.add_argument("--out", required=True, metavar="DIR", help="folder to write the run into")
    g = s.add_argument_group("regime (docs/sumo.md, Regimes)")
    g.add_argument("--lane-change-duration", type=float, default=3.0, metavar="S",
                   help="seconds a lane change takes (SUMO --lanechange.duration; default 3; 0 = instantaneous)")
    g.add_argument("--truck-share", type=float, default=0.15, metavar="X",
                   help="share of motor vehicles that are trucks (default 0.15)")
    g.add_argument("--bus-share", type=float, default=0.05, metavar="X",
                   help="share of motor vehicles that are buses or coaches (default 0.05)")
    g.add_argument("--demand", type=float, default=1.0, metavar="X", help="factor on every traffic flow (default 1)")
    g.add_argument("--approach-lanes", type=int, default=3, choices=[2, 3, 4],
                   help="junction: lanes per approach, i.e. its size (default 3)")
    g.add_argument("--no-creep", dest="creep", action="store_false",
                   help="junction: left-turners start from the line like other cars (default: they creep)")
    g = s.add_argument_group("perception-like noise, written to a perceived copy of the run (docs/evaluation.md)")
    g.add_argument("--perceived", metavar="DIR",
                   help="also write DIR/<run folder name>: the run with noisy tracks, for ingest; label the original")
    g.add_argument("--noise-position", type=float, default=0.0, metavar="M",
                   help="standard deviation of the x and y jitter, metres (default 0)")
    g.add_argument("--noise-heading", type=float, default=0.0, metavar="DEG",
                   help="standard deviation of the heading jitter, degrees (default 0)")
    g.add_argument("--noise-speed", type=float, default=0.0, metavar="MPS",
                   help="standard deviation of the speed noise, m/s (default 0)")
    g.add_argument("--noise-drop", type=float, default=0.0, metavar="X",
                   help="share of detections dropped at random (default 0; 0.02 = 2 %%)")
    g.add_argument("--noise-seed", type=int, metavar="N", help="seed of the noise (default: --seed)")

    la = _command(harness, "label", cmd_label, "ground-truth labels from a simulator's own records (for evaluate)",
                  "Label scenarios in SUMO run folders from SUMO's own records (FCD leader, lane-change output, "
                  "lanes and lane positions, vType boxes, the network's connections, signal states), independently "
                  "of logiq_sql's SQL; `logiq-sql eval evaluate` scores matches against them. Definitions: "
                  "docs/evaluation.md.", hidden)
    la.add_argument("source", choices=["sumo"], help="sumo: run folders written by logiq-sql eval simulate")
    la.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders, or folders holding them")
    la.add_argument("--out", required=True, metavar="FILE", help="labels Parquet file to write")
    la.add_argument("--scenario", action="append", metavar="NAME",
                    help="scenario to label (repeatable; default every scenario the labeller knows, "
                         "docs/evaluation.md)")
    _add_set(la)

    ev = _command(harness, "evaluate", cmd_evaluate, "score the matches of a DuckDB file against ground-truth labels",
                  "Per scenario: event-level precision, recall and F1 (one-to-one pairs at temporal IoU >= --iou) "
                  "and timestamp balanced accuracy over every frame of the egos the matcher used. Definitions: "
                  "docs/evaluation.md.", hidden)
    _add_db(ev, "DuckDB file after logiq-sql match")
    ev.add_argument("--labels", required=True, metavar="FILE",
                    help="labels Parquet (e.g. from logiq-sql eval label sumo)")
    ev.add_argument("--iou", type=float, default=0.5, metavar="X", help="IoU threshold of an event hit (default 0.5)")
    ev.add_argument("--out", metavar="DIR", help="write evaluation.parquet and evaluation_events.parquet into DIR")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="logiq-sql", description="Find LogIQ evaluation scenarios in drives with SQL over DuckDB.",
        epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"logiq-sql {version('logiq-sql')}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (add_ingest, add_match, add_scenarios, add_lint, add_new_scenario, add_render, add_explain, add_query,
                add_info, add_cache, add_report, add_replay, add_export, add_eval):
        add(sub)
    return parser


def _run(argv: list[str]) -> int:
    parser = build_parser()
    if not argv:
        parser.print_help()
        return EXIT_OK
    args = parser.parse_args(argv)
    if getattr(args, "renamed", None):
        print(f"logiq-sql: `{args.command}` is now `logiq-sql {args.renamed}`; the old name will be removed.",
              file=sys.stderr)
    try:
        return args.func(args)
    except LogiqError as exc:
        print(f"logiq-sql: error: {exc.render(FLAGS)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileBusyError as exc:
        print(f"logiq-sql: busy: {exc.render(FLAGS)}", file=sys.stderr)
        return EXIT_BUSY
    except DiskFullError as exc:
        print(f"logiq-sql: disk full: {exc.render(FLAGS)}", file=sys.stderr)
        return EXIT_DISK_FULL


def main(argv: list[str] | None = None) -> int:
    try:
        return _run(sys.argv[1:] if argv is None else list(argv))
    except BrokenPipeError:  # the reader closed the pipe (`logiq-sql scenarios | head`): nothing left to say
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the interpreter's last flush does not fail again
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
