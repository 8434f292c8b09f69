"""The ``logiq-sql`` command: one function per command (``cmd_*``) and one per command's options (``add_*``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from importlib.metadata import version
from pathlib import Path

from logiq_sql.cli.common import (
    EPILOG,
    EXIT_BAD_INPUT,
    EXIT_BUSY,
    EXIT_DISK_FULL,
    EXIT_OK,
    EXIT_REJECTED,
    add_db,
    add_ego_kinds,
    add_quiet,
    add_relation_range,
    add_scenario_path,
    add_set,
    add_wait,
    command,
    db_of,
    set_pairs,
)
from logiq_sql.cli.harness import add_eval
from logiq_sql.core.errors import DiskFullError, FileBusyError, LogiqError
from logiq_sql.core.formats import FORMATS, formats_help

# how the CLI spells the Python arguments that library errors name (logiq_sql.core.errors.arg)
FLAGS = {"overrides": "--set", "drives": "--drive", "db_path": "--db", "name": "NAME", "wait_s": "--wait"}
QUERY_FORMATS = ("table", "csv", "json", "markdown")
TABLE_ROWS = 40  # rows `query --format table` prints unless --limit says otherwise


def _say(quiet: bool):
    return None if quiet else (lambda msg: print(msg, file=sys.stderr))


def cmd_ingest(args: argparse.Namespace) -> int:
    from logiq_sql.ingestion.ingest import ingest

    if args.db is not None and args.dataset is not None:
        raise LogiqError("ingest: give either --db FILE (a DuckDB file) or --dataset DIR (Parquet, docs/engines.md).")
    if args.dataset is not None:
        from logiq_sql.ingestion.dataset_ingest import ingest_dataset

        summary = ingest_dataset(args.format, args.paths, args.dataset, progress=_say(args.quiet))
        print(f"{args.dataset}: {summary}")
        if summary.rejected:
            print(f"{summary.rejected} drive(s) rejected, each with its reason in {args.dataset}/drive_inputs "
                  "(status = 'rejected', reject_reason)")
            return EXIT_REJECTED
        return EXIT_OK
    db = db_of(args)
    summary = ingest(args.format, args.paths, db, progress=_say(args.quiet), wait_s=args.wait)
    print(f"{db}: {summary}")
    if summary.rejected:
        print(f"{summary.rejected} drive(s) rejected, each with its reason: logiq-sql query --db {db} "
              "\"select drive_id, source_path, reject_reason from drives where status = 'rejected'\"")
        return EXIT_REJECTED
    return EXIT_OK


def cmd_match(args: argparse.Namespace) -> int:
    from logiq_sql.matching.match import match, match_dataset

    if args.dataset is not None and not args.out:
        raise LogiqError("match --dataset DIR: give --out DIR too (the results file is then OUT/logiq.duckdb).")
    common = dict(scenarios=args.scenario or None, ego=args.ego, overrides=set_pairs(args.set),
                  drives=args.drive or None, relation_range=args.relation_range, progress=_say(args.quiet),
                  force=args.force, engine=args.engine, spark_master=args.spark_master, wait_s=args.wait,
                  scenario_path=args.scenario_path, ego_kinds=args.ego_kinds, keep=args.keep,
                  step_cache=args.step_cache)
    if args.dataset is not None:  # with --engine spark, Spark writes the results itself under --out
        result = match_dataset(args.dataset, args.out, args.db, spark_tables=args.spark_tables or args.dataset,
                               **common)
    else:
        result = match(db_of(args), out=args.out, spark_tables=args.spark_tables, **common)
    print(result.summary())
    if args.out:
        print(f"Parquet written to {Path(args.out).resolve()}")
    return EXIT_OK


def cmd_scenarios(args: argparse.Namespace) -> int:
    from logiq_sql.spec.scenario import list_scenarios

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
    from logiq_sql.matching.match import render

    print(render(args.scenario, overrides=set_pairs(args.set), ego=args.ego, relation_range=args.relation_range,
                 engine=args.engine, scenario_path=args.scenario_path, ego_kinds=args.ego_kinds))
    return EXIT_OK


def cmd_explain(args: argparse.Namespace) -> int:
    from logiq_sql.matching.explain import explain

    result = explain(db_of(args), args.scenario, args.drive, args.ego, actor=args.actor,
                     overrides=set_pairs(args.set), relation_range=args.relation_range,
                     scenario_path=args.scenario_path, ego_kinds=args.ego_kinds)
    print(result.text())
    return EXIT_OK


def cmd_lint(args: argparse.Namespace) -> int:
    from logiq_sql.cli.lint import lint_scenarios

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
    db = db_of(args)
    if not Path(db).is_file():
        raise LogiqError(f"--db {db}: no such file (write one with `logiq-sql ingest`).")
    return db


def cmd_query(args: argparse.Namespace) -> int:
    import duckdb
    import polars as pl

    from logiq_sql.storage import tables
    from logiq_sql.storage.db import open_for_read

    db = _existing_db(args)
    if args.limit is not None and args.limit < 0:
        raise LogiqError(f"--limit {args.limit}: give a number of rows >= 0 (0: every row).")
    with open_for_read(db) as con:
        try:
            frame = con.sql(args.sql).pl()
        except duckdb.Error as exc:  # the analyst's SQL: a bad-input error, not a crash
            hint = "the tables and their columns are in docs/tables.md."
            if isinstance(exc, duckdb.BinderException | duckdb.CatalogException):
                # a column or view the SQL names may be one added since an earlier logiq_sql wrote the file
                hint = tables.outdated(con, db) or hint
            raise LogiqError(f"{exc}\n\nHint: {hint}") from None
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
    from logiq_sql.storage.db import open_for_read

    db = db_of(args)
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
    from logiq_sql.spec.scaffold import new_scenario

    for path in new_scenario(args.name, args.extends, args.dir):
        print(f"wrote {path}")
    print(f"next: logiq-sql lint {args.name} --scenario-path {args.dir}; then logiq-sql match --scenario-path "
          f"{args.dir} --scenario {args.name} (the contract: docs/scenarios.md)")
    return EXIT_OK


def cmd_cache(args: argparse.Namespace) -> int:
    from logiq_sql.storage import step_cache

    db = _existing_db(args)
    if not step_cache.path_of(db).is_file():
        print(f"step cache of {db}: none ({step_cache.path_of(db)} is made by the first match that keeps steps)")
        return EXIT_OK
    with step_cache.opened(db, args.wait) as con:  # a run writing the file holds its cache open
        if args.clear:
            step_cache.clear(con)
        print(f"step cache of {db} ({step_cache.path_of(db)}): {step_cache.describe(step_cache.size(con))}")
    return EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from logiq_sql.outputs.report import report

    print(f"report written to {report(db_of(args), args.out).resolve()}")
    return EXIT_OK


def cmd_replay(args: argparse.Namespace) -> int:
    from logiq_sql.outputs.replay import save

    print(f"replay of {args.match_id} written to {save(db_of(args), args.match_id, args.out, args.step).resolve()}")
    return EXIT_OK


def cmd_export_xosc(args: argparse.Namespace) -> int:
    from logiq_sql.outputs.export.xosc import export_xosc

    done = export_xosc(db_of(args), args.match_id, args.out, convert_map=args.convert_map)
    vertices = ", ".join(f"{who} {n}" for who, n in done.vertices.items())
    print(f"OpenSCENARIO written to {done.path.resolve()} (trajectory vertices: {vertices}; {done.map_reference})")
    return EXIT_OK


def cmd_export_openlabel(args: argparse.Namespace) -> int:
    from logiq_sql.outputs.export.openlabel import export_openlabel

    files = export_openlabel(db_of(args), args.out, drives=args.drive or None)
    print(f"{len(files)} OpenLABEL file(s) written to {Path(args.out).resolve()}")
    return EXIT_OK


def add_ingest(sub) -> None:
    p = command(sub, "ingest", cmd_ingest, "read drives into a DuckDB file",
                 "Read drives (files or folders of them) into the canonical tables of a DuckDB file. Re-ingesting a "
                 "drive replaces it.")
    p.add_argument("format", choices=list(FORMATS), help=formats_help())
    p.add_argument("paths", nargs="+", metavar="PATH", help="files or folders")
    add_db(p, "DuckDB file to create or update")
    p.add_argument("--dataset", metavar="DIR", help="instead of --db: write the canonical tables as Parquet "
                   "partitioned by drive into DIR, file by file, so many machines can ingest into one DIR "
                   "(docs/engines.md)")
    add_quiet(p)
    add_wait(p)


def add_match(sub) -> None:
    p = command(sub, "match", cmd_match, "match scenarios against the drives of a DuckDB file",
                 "Match scenarios and store matches, match_phases, kpis and coverage in the file.")
    add_db(p, "DuckDB file written by ingest (with --dataset: the results file, default OUT/logiq.duckdb)")
    p.add_argument("--dataset", metavar="DIR", help="match the Parquet dataset written by ingest --dataset; --db "
                   "then gets views over it beside the results (docs/engines.md)")
    p.add_argument("--scenario", action="append", metavar="NAME", help="scenario to match (repeatable; default all)")
    p.add_argument("--ego", default="auto", metavar="auto|recorded|all|every:N|IDS",
                   help="who is the SUT: auto (recorded ego, else every actor of an ego kind: car, truck, bus, ...; "
                        "default), recorded, all (every actor of an ego kind), every:N, or actor ids, comma-separated")
    add_ego_kinds(p)
    add_scenario_path(p)
    add_set(p)
    p.add_argument("--drive", action="append", metavar="ID", help="only these drives (repeatable)")
    add_relation_range(p)
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
    p.add_argument("--step-cache", metavar="auto|all|off", default=None,  # checked by step_cache.mode
                   help="what the step cache beside the file (FILE.step_cache) keeps for the next runs: auto (the "
                        "steps that cost more to compute than to keep), all, or off (nothing kept or read: no disk "
                        "beside the file, every later run computes everything). Default: $LOGIQ_SQL_STEP_CACHE, "
                        "else auto")
    add_quiet(p)
    add_match_engine(p)
    add_wait(p)


def add_match_engine(p: argparse.ArgumentParser) -> None:
    """What runs the queries of match, and where Spark reads the tables."""
    p.add_argument("--engine", choices=["duckdb", "spark", "polars"], default="duckdb",
                   help="what runs the queries: duckdb (default), spark (pip install 'logiq-sql[spark]', Java 17) "
                        "or polars (Polars SQL, with its overrides: docs/engines.md). Results land "
                        "in --db either way")
    p.add_argument("--spark-master", metavar="URL",
                   help="Spark master for --engine spark (default: $SPARK_MASTER, else local[2])")
    p.add_argument("--spark-tables", metavar="DIR",
                   help="where --engine spark writes the canonical tables as Parquet (partitioned by drive_id) for "
                        "Spark to read; on a cluster, a folder every executor can read (default: a temporary folder)")


def add_scenarios(sub) -> None:
    p = command(sub, "scenarios", cmd_scenarios, "list scenarios with their parameters, defaults and descriptions")
    p.add_argument("--all", action="store_true", help="include the base scenarios")
    p.add_argument("--format", choices=["table", "json"], default="table",
                   help="table (default) or json: a list of scenarios, each with its parameters (name, type, "
                        "default, description, declared_in), phases, KPIs and coverage items")
    add_scenario_path(p)


def add_lint(sub) -> None:
    p = command(sub, "lint", cmd_lint, "check scenarios against their SQL, before any data is read",
                 "Load each scenario (every key of every table, with did-you-mean), check the parameters each SQL "
                 "file uses, the columns each phase, KPI and sample query returns against what the scenario "
                 "declares, and the SQL's portability. Problems name the file and key; exit 2 when there is any.")
    p.add_argument("scenario", nargs="*", metavar="SCENARIO", help="scenarios to check (default: all)")
    add_scenario_path(p)


def add_new_scenario(sub) -> None:
    p = command(sub, "new-scenario", cmd_new_scenario, "start a scenario of your own: a TOML file and its SQL",
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
    p = command(sub, "render", cmd_render, "print the SQL that matches a scenario, with its parameters set",
                 "Print one statement that finds the scenario's matches: SET VARIABLE lines bind the parameters, "
                 "then the query files as CTEs. Runs as-is in DuckDB against a file written by ingest. With "
                 "--engine spark: the same steps in Spark SQL, the parameter values listed as comments, to bind "
                 "with spark.sql(text, args=...).")
    p.add_argument("scenario", metavar="SCENARIO")
    add_set(p)
    p.add_argument("--ego", default="auto", help="as for match")
    add_ego_kinds(p)
    add_scenario_path(p)
    add_relation_range(p)
    p.add_argument("--engine", choices=["duckdb", "spark"], default="duckdb",
                   help="duckdb (default): SET VARIABLE lines and the statement; spark: the Spark SQL statement with "
                        "the values to bind (spark.sql(text, args=...)) listed as comments above it")


def add_explain(sub) -> None:
    p = command(sub, "explain", cmd_explain,
                 "why a scenario did not match: the first phase and condition that failed",
                 "Rerun a scenario's steps for one drive and ego (read-only) and print, for each actor its first "
                 "phase considers, how many phases it got through and, where it stopped, the conditions of the next "
                 "phase that failed, with the measured values, and where a gap or a flicker of at most max_gap was "
                 "bridged. Every scenario.")
    add_db(p, "DuckDB file written by ingest")
    p.add_argument("--scenario", required=True, metavar="NAME")
    p.add_argument("--drive", required=True, metavar="ID")
    p.add_argument("--ego", required=True, metavar="IDS", help="the ego's actor id(s), comma-separated, or recorded")
    p.add_argument("--actor", metavar="ID", help="only this actor")
    add_ego_kinds(p)
    add_scenario_path(p)
    add_set(p)
    add_relation_range(p)


def add_query(sub) -> None:
    p = command(sub, "query", cmd_query, "run read-only SQL against a DuckDB file and print the rows",
                 "Run read-only SQL against the file (as the last completed run published it) and print the rows, "
                 "floats with every digit. A write or a bad query is exit 2. Tables: docs/tables.md.")
    p.add_argument("sql", metavar="SQL")
    add_db(p)
    p.add_argument("--format", choices=QUERY_FORMATS, default="table",
                   help="table (default), csv, json (a list of rows) or markdown")
    p.add_argument("--limit", type=int, metavar="N",
                   help=f"print at most N rows, 0 for all (default: {TABLE_ROWS} for table, all for the others); "
                        "when rows are left out, stderr says how many")


def add_info(sub) -> None:
    p = command(sub, "info", cmd_info, "say what a file holds: drives by source and status, runs, matches",
                 "What a logiq_sql file holds: its drives by source format and status, track rows, the match runs, "
                 "and per scenario the matches and the drives matched.")
    add_db(p)


def add_cache(sub) -> None:
    p = command(sub, "cache", cmd_cache, "the size of the step cache of a DuckDB file, or --clear it",
                 "match keeps the rows of its steps in FILE.step_cache beside the file and reads them back when a "
                 "later run needs the same step (same SQL, values and drive rows): docs/operations.md, 'The step "
                 "cache'. Re-ingesting a drive drops its entries; --clear drops all. A run writing the file holds "
                 "the cache: --wait waits for it.")
    add_db(p)
    add_wait(p)
    p.add_argument("--clear", action="store_true", help="drop every entry of the cache")


def add_report(sub) -> None:
    p = command(sub, "report", cmd_report, "write one self-contained HTML report of a matched file",
                 "Coverage histograms, KPI distributions, the match table with filters, every drive's status and "
                 "the runs with their parameters, in one HTML file with inline SVG charts (no network needed to "
                 "view it).")
    add_db(p)
    p.add_argument("--out", required=True, metavar="FILE", help="HTML file to write, e.g. report.html")


def add_replay(sub) -> None:
    p = command(sub, "replay", cmd_replay, "write the animated bird's-eye replay of one match as a GIF or an MP4",
                 "The replay the report shows (lanes, junctions, the ego and the actor as boxes, the phases on a "
                 "timeline, gap, headway, TTC and speeds), as a GIF (Pillow) or an MP4 (ffmpeg from "
                 "imageio-ffmpeg). match_id: the matches table's first column.")
    p.add_argument("match_id", metavar="MATCH_ID")
    add_db(p)
    p.add_argument("--out", required=True, metavar="FILE", help="file to write: .gif or .mp4")
    p.add_argument("--step", type=int, default=None, metavar="N",
                   help="draw every N-th frame (default: at most 150 frames)")


def add_export(sub) -> None:
    p = sub.add_parser("export", help="write a match as OpenSCENARIO or the drives' matches as OpenLABEL",
                       epilog=EPILOG, description="Export into standard formats (mappings: docs/formats.md).")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="FORMAT")
    x = command(kinds, "xosc", cmd_export_xosc,
                 "one match as an OpenSCENARIO 1.3 file: ego and actor replay their tracks")
    x.add_argument("match_id", metavar="MATCH_ID", help="matches.match_id")
    add_db(x)
    x.add_argument("--out", required=True, metavar="FILE", help="the .xosc file to write")
    x.add_argument("--convert-map", action="store_true",
                   help="for a drive on a SUMO network (still in its run folder): write the network as OpenDRIVE "
                        "beside the .xosc with netconvert (the [sumo] extra) and reference it")
    o = command(kinds, "openlabel", cmd_export_openlabel,
                 "one ASAM OpenLABEL 1.0 JSON file per drive: tags, objects, phases, KPIs")
    add_db(o)
    o.add_argument("--out", required=True, metavar="DIR", help="folder to write {drive_id}.json into")
    o.add_argument("--drive", action="append", metavar="ID", help="only these drives (repeatable; default all "
                                                                   "ingested drives)")


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

