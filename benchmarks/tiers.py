"""Benchmark tiers: the whole pipeline (ingest, localisation, relations, all four scenarios, KPIs, coverage)
on S (~1 M track rows), M (~10 M) and L (>= 50 M), against a plain DuckDB scan measured in the same run.

    make bench TIER=S                       # = python -m benchmarks.tiers --tier S
    python -m benchmarks.tiers --tier M --ego every:10
    python -m benchmarks.tiers --tier S --engine polars   # also re-match with the Polars engine, same run
    python -m benchmarks.tiers --tier S --baseline-only --db COPY.duckdb  # only the per-pair baseline comparison

Input. The base drives are the bundled real drives (tests/data: 92 NGSIM scenes via CommonRoad, 4 nuScenes
scenes via ScenarioNet, 5 Argoverse 2 logs) and SUMO drives: the bundled motorway and junction runs and, when
the [sumo] extra is installed, motorway seeds 2 and 3 and junction seed 2 (5 simulated minutes each, generated
once into benchmarks/work/base and reused). They are exported as canonical Parquet and replicated, drive by
drive in a fixed shuffled order, until the tier's row count is reached: copy k gets drive ids suffixed ``~k``
and its times and frames shifted by k hours (maps are shared, as a fleet driving the same roads would).

SUT: ``--ego every:10`` (default): every 10th vehicle of each drive by actor id, plus the recorded ego where
the drive has one (nuScenes, Argoverse 2).

Measured in one process, in this order: the floor (a plain DuckDB scan and group-by over the tier's track
columns), ingest of the replicated Parquet (kinematics SQL, shapely localisation, writing the file), matching
every scenario with KPIs and coverage, re-matching everything (match --force) with and without the step cache,
re-matching after one parameter of one scenario changed (PARAM_CHANGE) and after it changed back, the floor again
(the faster floor is used). Each stage's wall time, rows
per second and peak resident memory come from logiq_sql.core.timing. At tier S the per-pair baseline
(benchmarks/baseline.py) runs on the same file, is checked to give the same matches, and is timed against the
SQL matcher on the same two scenarios. Written: benchmarks/results/<TIER>.json and <TIER>.md.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import multiprocessing
import os
import platform
import resource
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.timing import cpu_seconds, recording
from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.match import match
from logiq_sql.storage import step_cache
from logiq_sql.storage.db import memory_limit

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
WORK = ROOT / "benchmarks" / "work"
RESULTS = ROOT / "benchmarks" / "results"
TIERS = {"S": 1_000_000, "M": 10_000_000, "L": 50_000_000}
GENERATED_SUMO = (("motorway", 2), ("motorway", 3), ("junction", 2))  # 5 simulated minutes each
BASE_VERSION = "1"  # bump when the base drives change, so the cached base is rebuilt
PER_DRIVE = ("tracks", "traffic_light_states")
FLOOR_SQL = """
select drive_id, actor_id, count(*), min(t_s), max(t_s), avg(x_m), avg(y_m), avg(speed_mps), max(accel_mps2)
from read_parquet($path)
group by drive_id, actor_id
"""
# the parameter change of the param_rematch stage: one parameter of one scenario, read by its phase query; and one
# read only by the generic steps after the phases (a phase's least duration), measured after it
PARAM_CHANGE = ("follower_vehicle", {"same_road_limit": "8sec"})
DURATION_CHANGE = ("follower_vehicle", {"min_scenario_duration": "2sec"})
BASELINE_SCENARIOS = ("follower_vehicle", "cyclist_close_to_moving_sut")
# each tier's outputs from the code before a speed change (written with --write-golden), compared on every run:
# a lever that changes a match, phase or KPI shows here at scale, not only on the bundled drives (tests/golden.py)
GOLDEN = ROOT / "benchmarks" / "golden"
GOLDEN_TABLES = {
    "matches": "select * exclude (run_id) from matches order by scenario, drive_id, ego_id, actor_id, start_frame",
    "match_phases": "select * from match_phases order by match_id, phase_index",
    "kpis": "select * from kpis order by scenario, match_id",
}


def write_results(name: str, report: dict, text: str) -> None:
    """benchmarks/results/<name>.json (the report) and .md (its text), and the text printed."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(report, indent=2))
    (RESULTS / f"{name}.md").write_text(text if text.endswith("\n") else text + "\n")
    print(text)
    print(f"written to {RESULTS / name}.json and .md")


def golden_check(db: Path, tier: str, write: bool) -> dict[str, object]:
    """Write (``write``) or compare the tier's matches, phases and KPIs with benchmarks/golden/<tier>_*.parquet."""
    from polars.testing import assert_frame_equal

    with duckdb.connect(str(db), read_only=True) as con:
        got = {name: con.sql(sql).pl() for name, sql in GOLDEN_TABLES.items()}
    if write:
        GOLDEN.mkdir(parents=True, exist_ok=True)
        for name, frame in got.items():
            frame.write_parquet(GOLDEN / f"{tier}_{name}.parquet", compression="zstd", compression_level=19)
        return {"written": True}
    out: dict[str, object] = {}
    for name, frame in got.items():
        path = GOLDEN / f"{tier}_{name}.parquet"
        if not path.exists():
            out[name] = "no golden"
            continue
        want = pl.read_parquet(path)
        try:
            assert_frame_equal(frame.select(want.columns), want, check_exact=False, rel_tol=1e-9, abs_tol=1e-12)
            out[name] = "same"
        except (AssertionError, pl.exceptions.ColumnNotFoundError) as exc:
            out[name] = f"DIFFERENT: {str(exc).splitlines()[0]}"
    return out


def build_base(base: Path) -> list[str]:
    """Ingest the base drives and export their canonical tables as Parquet into ``base``; returns the sources."""
    db = base / "base.duckdb"
    sources = ["tests/data/commonroad_ngsim", "tests/data/nuscenes_mini_scenarionet", "tests/data/av2",
               "tests/data/sumo/motorway_s1", "tests/data/sumo/junction_s1"]
    ingest("commonroad", [DATA / "commonroad_ngsim"], db)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet"], db)
    ingest("av2", [DATA / "av2"], db)
    runs = [DATA / "sumo" / "motorway_s1", DATA / "sumo" / "junction_s1"]
    try:
        from logiq_sql.evaluation.simulate import simulate

        for kind, seed in GENERATED_SUMO:
            out = base / "sumo" / f"{kind}_s{seed}"
            simulate(kind, 5.0, seed, out)
            runs.append(out)
            sources.append(f"logiq-sql simulate {kind} --minutes 5 --seed {seed}")
    except ImportError:
        print("SUMO is not installed ([sumo] extra): the base has the bundled SUMO runs only", file=sys.stderr)
    ingest("sumo", runs, db)
    with duckdb.connect(str(db), read_only=True) as con:
        for table in ("drive_inputs", *PER_DRIVE, *schema.MAP_TABLE_NAMES):
            con.execute(f"copy (select * from {table}) to '{base / table}.parquet' (format parquet)")
    (base / "sources.json").write_text(json.dumps({"version": BASE_VERSION, "sources": sources}, indent=2))
    return sources


def base_sources() -> list[str]:
    base = WORK / "base"
    stamp = base / "sources.json"
    if stamp.exists() and json.loads(stamp.read_text()).get("version") == BASE_VERSION:
        return json.loads(stamp.read_text())["sources"]
    shutil.rmtree(base, ignore_errors=True)
    base.mkdir(parents=True)
    return build_base(base)


def replicate(rows: int, out: Path) -> int:
    """Write the tier's canonical Parquet into ``out``: base drives, copy after copy, until ``rows`` track rows."""
    base = WORK / "base"
    drives = pl.read_parquet(base / "drive_inputs.parquet").filter(pl.col("status") == "ingested")
    tracks = pl.scan_parquet(base / "tracks.parquet")
    sizes = tracks.group_by("drive_id").len().collect()
    # a fixed shuffled order, so that a tier cut short of a whole copy still mixes the sources
    order = (drives.join(sizes, on="drive_id")
             .with_columns(key=pl.col("drive_id").map_elements(lambda d: hashlib.md5(d.encode()).hexdigest(),
                                                               return_dtype=pl.String))
             .sort("key"))
    picks, total, k = [], 0, 0
    while total < rows:
        for d in order.iter_rows(named=True):
            if total >= rows:
                break
            picks.append((d["drive_id"], k, round(3600.0 * k / d["dt_s"])))
            total += d["len"]
        k += 1
    plan = pl.DataFrame(picks, schema={"drive_id": pl.String, "copy": pl.Int64, "frame_shift": pl.Int64},
                        orient="row")
    out.mkdir(parents=True, exist_ok=True)

    def copied(frame: pl.LazyFrame) -> pl.LazyFrame:
        # as a fleet's logs come: drive after drive in the plan's order, each drive's rows in the base's own
        # (actor, frame) order (an unordered join dealt the copies of a row out side by side)
        shifted = frame.join(plan.lazy(), on="drive_id", maintain_order="right_left").with_columns(
            pl.col("drive_id") + "~" + pl.col("copy").cast(pl.String),
            pl.col("frame") + pl.col("frame_shift"))
        if "t_s" in frame.collect_schema().names():
            shifted = shifted.with_columns(pl.col("t_s") + 3600.0 * pl.col("copy"))
        return shifted.drop("copy", "frame_shift")

    copied(tracks.select(schema.TRACKS.column_names)).sink_parquet(out / "tracks.parquet", row_group_size=500_000)
    copied(pl.scan_parquet(base / "traffic_light_states.parquet")).sink_parquet(out / "traffic_light_states.parquet")
    (drives.join(plan, on="drive_id")
     .with_columns(pl.col("drive_id") + "~" + pl.col("copy").cast(pl.String))
     .select("drive_id", "dt_s", "map_id", "ego_actor_id", "attribution")
     .write_parquet(out / "drives.parquet"))
    for table in schema.MAP_TABLE_NAMES:
        shutil.copy(base / f"{table}.parquet", out / f"{table}.parquet")
    return total


def prepare(rows: int, out: Path) -> tuple[int, list[str]]:
    sources = base_sources()
    return replicate(rows, out), sources


def floor_s(path: Path) -> tuple[float, float]:
    """Wall and CPU seconds of the floor query."""
    start, cpu = time.perf_counter(), cpu_seconds()
    with duckdb.connect() as con:
        con.execute(FLOOR_SQL, {"path": str(path)}).fetchall()
    return time.perf_counter() - start, cpu_seconds() - cpu


@contextlib.contextmanager
def step_cache_mode(mode: str):
    """$LOGIQ_SQL_STEP_CACHE set to ``mode`` inside the block (logiq_sql/storage/step_cache.py)."""
    before = os.environ.get(step_cache.MODE_ENV)
    os.environ[step_cache.MODE_ENV] = mode
    try:
        yield
    finally:
        if before is None:
            del os.environ[step_cache.MODE_ENV]
        else:
            os.environ[step_cache.MODE_ENV] = before


def param_rematch(db: Path, ego: str, change: tuple[str, dict[str, str]]) -> dict[str, object]:
    """An analyst's re-match: one parameter of one scenario changed (``change``), every scenario asked for, as
    ``match --set`` would; the others are up to date and the step cache gives the steps the change leaves alone.
    Then the parameter back to its default (timed too), so the file holds the default results the golden check
    compares."""
    scenario, override = change
    out: dict[str, object] = {"scenario": scenario, "override": override}
    for label, overrides in (("", override), ("back_", {})):
        start, cpu = time.perf_counter(), cpu_seconds()
        result = match(db, ego=ego, overrides=overrides)
        out[f"{label}seconds"], out[f"{label}cpu_seconds"] = time.perf_counter() - start, cpu_seconds() - cpu
        out[f"{label}cache"] = result.cache
        out[f"{label}up_to_date"] = result.up_to_date
    return out


def run_baseline(db: Path, ego: str) -> dict[str, object]:
    """Time the SQL matcher and the per-pair baseline on the baseline's two scenarios, with the meaning the baseline
    implements (baseline.SAME_MEANING), and check that they find exactly the same matches. Wall and CPU seconds
    (all threads) of each side: on a shared machine the CPU ratio is the steadier one. Writes matches into ``db``."""
    sys.path.insert(0, str(ROOT))
    from benchmarks import baseline

    start, cpu = time.perf_counter(), cpu_seconds()
    # force: the drives were just matched, and an up-to-date run would be skipped
    match(db, scenarios=list(BASELINE_SCENARIOS), ego=ego, force=True, overrides=baseline.SAME_MEANING)
    sql_s, sql_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    start, cpu = time.perf_counter(), cpu_seconds()
    found = baseline.run(db, baseline.SAME_MEANING)
    seconds, seconds_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    with duckdb.connect(str(db), read_only=True) as con:
        ours = con.sql("select scenario, drive_id, ego_id, actor_id, start_frame, end_frame from matches").pl()
    agree = {}
    for name, frame in found.items():
        mine = set(ours.filter(pl.col("scenario") == name).drop("scenario").iter_rows())
        theirs = {(r.drive_id, r.ego_id, r.actor_id, int(r.start_frame), int(r.end_frame))
                  for r in frame.itertuples()}
        agree[name] = {"sql": len(mine), "baseline": len(theirs), "same": mine == theirs,
                       "sql_only": sorted(mine - theirs), "baseline_only": sorted(theirs - mine)}
    return {"baseline_s": seconds, "sql_s": sql_s, "ratio_to_baseline": seconds / sql_s,
            "baseline_cpu_s": seconds_cpu, "sql_cpu_s": sql_cpu, "cpu_ratio_to_baseline": seconds_cpu / sql_cpu,
            "matches": agree}


def baseline_markdown(b: dict) -> str:
    return (f"**Per-pair baseline** (follower_vehicle + cyclist_close_to_moving_sut): {b['baseline_s']:.1f} s, "
            f"CPU {b['baseline_cpu_s']:.1f} s, vs the SQL matcher's {b['sql_s']:.1f} s, CPU {b['sql_cpu_s']:.1f} s, "
            f"on the same two scenarios: **{b['ratio_to_baseline']:.1f}x** wall, "
            f"**{b['cpu_ratio_to_baseline']:.1f}x** CPU; same matches: "
            + ", ".join(f"{k} {v['sql']} / {v['baseline']} ({'identical' if v['same'] else 'DIFFERENT'})"
                        for k, v in b["matches"].items()) + ".")


def baseline_only(db: Path, ego: str, tier: str) -> dict:
    """The baseline comparison alone on an ingested file (it re-matches the two scenarios into it: pass a copy)."""
    report = {"db": str(db), "ego": ego, "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "load_average": os.getloadavg(), **run_baseline(db, ego)}
    text = (f"# Tier {tier}: per-pair baseline only, on {db.name}\n\nMeasured {report['measured_at']}, load average "
            + " / ".join(f"{x:.1f}" for x in report["load_average"]) + " (1 / 5 / 15 min) at the start.\n\n"
            + baseline_markdown(report) + "\n")
    write_results(f"{tier}_baseline", report, text)
    return report


def outputs_against(reference: Path, other: Path) -> dict[str, str]:
    """``same`` or the first difference, per table of GOLDEN_TABLES, of ``other``'s outputs against ``reference``'s
    (floats within 1e-9 relative: another engine's sums and cos/sin may differ in the last bits)."""
    from polars.testing import assert_frame_equal

    same: dict[str, str] = {}
    with duckdb.connect(str(reference), read_only=True) as a, duckdb.connect(str(other), read_only=True) as b:
        for name, sql in GOLDEN_TABLES.items():
            try:
                assert_frame_equal(b.sql(sql).pl(), a.sql(sql).pl(), check_exact=False, rel_tol=1e-9, abs_tol=1e-12)
                same[name] = "same"
            except AssertionError as exc:
                same[name] = f"DIFFERENT: {str(exc).splitlines()[0]}"
    return same


def engine_rematch(db: Path, engine: str, ego: str, duckdb_s: float, duckdb_cpu_s: float) -> dict[str, object]:
    """Re-match a copy of the ingested file with another engine (every drive, every scenario), timed against DuckDB's
    re-match of the same run, and compare the outputs of GOLDEN_TABLES with DuckDB's (floats within 1e-9)."""

    copy = db.with_name(f"{db.stem}_{engine}.duckdb")
    shutil.copy(db, copy)
    start, cpu = time.perf_counter(), cpu_seconds()
    match(copy, ego=ego, force=True, engine=engine)
    seconds, cpu_s = time.perf_counter() - start, cpu_seconds() - cpu
    same = outputs_against(db, copy)
    copy.unlink()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # run in a child process: this engine's own
    return {"seconds": seconds, "cpu_seconds": cpu_s, "peak_rss_bytes": peak, "duckdb_seconds": duckdb_s, "duckdb_cpu_seconds": duckdb_cpu_s,
            "ratio_to_duckdb": seconds / duckdb_s, "cpu_ratio_to_duckdb": cpu_s / duckdb_cpu_s, "outputs": same}


def engine_rematch_apart(db: Path, engine: str, ego: str, duckdb_s: float, duckdb_cpu_s: float) -> dict[str, object]:
    """engine_rematch in a child process, so the peak memory of this process stays DuckDB's own; a child that
    dies (the OOM killer: the Polars engine holds whole tables in memory) is reported, not waited for."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        try:
            return pool.submit(engine_rematch, db, engine, ego, duckdb_s, duckdb_cpu_s).result()
        except BrokenProcessPool:
            db.with_name(f"{db.stem}_{engine}.duckdb").unlink(missing_ok=True)
            return {"failed": "the child process died (killed by a signal: on Linux, the OOM killer when memory "
                              "runs out; dmesg says)", "duckdb_seconds": duckdb_s}


def markdown(r: dict) -> str:
    p, d = r["param_rematch"], r["duration_rematch"]
    lines = [f"# Tier {r['tier']}: {r['rows']:,} track rows, {r['drives']:,} drives, ego {r['ego']}", "",
             f"Measured {r['measured_at']} on {r['machine']}. Floor (plain DuckDB scan + group-by): "
             f"{r['floor_s']:.2f} s ({r['rows'] / r['floor_s']:,.0f} rows/s).", "",
             "| stage | wall s | rows/s | x floor | CPU s | peak RSS GiB |", "|---|---:|---:|---:|---:|---:|"]
    for name, s in r["stages"].items():
        lines.append(f"| {name} | {s['seconds']:.2f} | {s['rows_per_s']:,.0f} | {s['ratio_to_floor']:.1f} | "
                     f"{s['cpu_seconds']:.2f} | {s['peak_rss_bytes'] / 2**30:.2f} |")
    lines += ["", f"**Pipeline**: {r['pipeline_s']:.1f} s = **{r['ratio_to_floor']:.1f}x the floor**; "
              f"peak RSS {r['peak_rss_bytes'] / 2**30:.2f} GiB; {r['matches']:,} matches; "
              f"{r['rows'] / r['pipeline_s']:,.0f} rows/s, {1e6 * r['pipeline_s'] / r['rows']:.2f} µs per row. "
              f"CPU (all threads): pipeline {r['pipeline_cpu_s']:.1f} s against the floor's {r['floor_cpu_s']:.2f} s "
              f"= {r['cpu_ratio_to_floor']:.1f}x.", "",
              f"**Re-matching** (match --force on the ingested file): {r['rematch_s']:.1f} s = "
              f"{r['rematch_rows_per_s']:,.0f} rows/s, {r['rematch_ratio_to_floor']:.1f}x the floor; "
              f"CPU {r['rematch_cpu_s']:.1f} s; with no step cache (LOGIQ_SQL_STEP_CACHE=off) "
              + (f"{r['rematch_nocache_s']:.1f} s, CPU {r['rematch_nocache_cpu_s']:.1f} s."
                 if r['rematch_nocache_s'] is not None else "not run (--no-nocache)."), "",
              f"**Re-matching after one parameter change** ({p['scenario']} {p['override']}, every scenario asked "
              f"for): {r['param_rematch_s']:.2f} s = {r['param_rematch_rows_per_s']:,.0f} rows/s, "
              f"{r['param_rematch_ratio_to_floor']:.1f}x the floor; CPU {p['cpu_seconds']:.1f} s; {p['cache']}. "
              f"Back to the default: {p['back_seconds']:.2f} s. A parameter only the steps after the phases read "
              f"({d['scenario']} {d['override']}): {d['seconds']:.2f} s, CPU {d['cpu_seconds']:.1f} s; "
              f"{d['cache'].split(';')[0]}.", "",
              "**Golden** (benchmarks/golden/, the outputs before the speed work): "
              + ", ".join(f"{k} {v}" for k, v in r["golden"].items()) + "."]
    for engine, e in r.get("engines", {}).items():
        if "failed" in e:
            lines += ["", f"**Re-matching with --engine {engine}**: did not finish: {e['failed']}."]
            continue
        lines += ["", f"**Re-matching with --engine {engine}** (a copy of the ingested file, every scenario, same run): "
                  f"{e['seconds']:.1f} s, CPU {e['cpu_seconds']:.1f} s, against DuckDB's {e['duckdb_seconds']:.1f} s, "
                  f"CPU {e['duckdb_cpu_seconds']:.1f} s: **{e['ratio_to_duckdb']:.2f}x DuckDB's wall time**, "
                  f"{e['cpu_ratio_to_duckdb']:.2f}x its CPU; peak RSS {e['peak_rss_bytes'] / 2**30:.2f} GiB; outputs against DuckDB's: "
                  + ", ".join(f"{k} {v}" for k, v in e["outputs"].items()) + "."]
    if r.get("baseline"):
        lines += ["", baseline_markdown(r["baseline"])]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", choices=list(TIERS), default="S")
    parser.add_argument("--rows", type=int, help="override the tier's row count (for trying the harness)")
    parser.add_argument("--ego", default="every:10", help="SUT choice (see match --ego; default every:10)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the per-pair baseline at tier S")
    parser.add_argument("--no-nocache", action="store_true",
                        help="skip the re-match with the step cache off (it doubles the re-match time at tier L)")
    parser.add_argument("--write-golden", action="store_true",
                        help="store this run's matches, phases and KPIs as the tier's golden (benchmarks/golden/)")
    parser.add_argument("--engine", action="append", default=[], choices=["polars"], dest="engines",
                        help="also re-match the ingested file with this engine and compare it with DuckDB's re-match")
    parser.add_argument("--baseline-only", action="store_true",
                        help="only compare the per-pair baseline with the SQL matcher on an ingested file (--db)")
    parser.add_argument("--db", type=Path, help="with --baseline-only: the ingested file (it is re-matched: a copy; "
                        "default benchmarks/work/<TIER>/bench.duckdb)")
    args = parser.parse_args(argv)
    if args.baseline_only:
        return baseline_only(args.db or WORK / args.tier / "bench.duckdb", args.ego, args.tier)
    rows = args.rows or TIERS[args.tier]
    work = WORK / args.tier
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    # the input is prepared in a child process, so the peak memory below is the pipeline's own
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        n, sources = pool.apply(prepare, (rows, work / "parquet"))
    tracks = work / "parquet" / "tracks.parquet"
    db = work / "bench.duckdb"

    floor_first = floor_s(tracks)
    with recording() as rec:
        start, cpu = time.perf_counter(), cpu_seconds()
        summary = ingest("parquet", [work / "parquet"], db)
        ingest_s, ingest_cpu = time.perf_counter() - start, cpu_seconds() - cpu
        start, cpu = time.perf_counter(), cpu_seconds()
        result = match(db, ego=args.ego)
        match_s, match_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    # re-matching after a parameter change: match again on the ingested file (force: every drive reruns)
    with recording() as rematch_rec:
        start, cpu = time.perf_counter(), cpu_seconds()
        match(db, ego=args.ego, force=True)
        rematch_s, rematch_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    # the same with no step cache (LOGIQ_SQL_STEP_CACHE=off): what keeping the steps costs a run that reuses none
    rematch_nocache_s = rematch_nocache_cpu = None
    if not args.no_nocache:
        with step_cache_mode("off"):
            start, cpu = time.perf_counter(), cpu_seconds()
            match(db, ego=args.ego, force=True)
            rematch_nocache_s, rematch_nocache_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    param = param_rematch(db, args.ego, PARAM_CHANGE)
    duration = param_rematch(db, args.ego, DURATION_CHANGE)
    engines = {name: engine_rematch_apart(db, name, args.ego, rematch_s, rematch_cpu) for name in args.engines}
    floor_second = floor_s(tracks)
    floor, floor_cpu = min(floor_first, floor_second)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

    stages = {"ingest (read, kinematics, write)": ingest_s - rec.seconds.get("localisation", 0.0)}
    stages |= {name: rec.seconds[name] for name in rec.seconds if name not in ("kinematics",)}
    stages["match: storing results"] = match_s - sum(v for k, v in rec.seconds.items()
                                                     if k not in ("kinematics", "localisation"))
    cpus = {"ingest (read, kinematics, write)": ingest_cpu - rec.cpu_seconds.get("localisation", 0.0)}
    cpus |= dict(rec.cpu_seconds)
    cpus["match: storing results"] = match_cpu - sum(v for k, v in rec.cpu_seconds.items()
                                                     if k not in ("kinematics", "localisation"))
    peaks = dict(rec.peak_rss_bytes)
    peaks["ingest (read, kinematics, write)"] = max(peaks.get("kinematics", 0), peaks.get("localisation", 0))
    report = {
        "tier": args.tier, "rows": n, "drives": summary.drives, "ego": args.ego, "sources": sources,
        "matches": result.matches.height,
        "matches_per_scenario": dict(result.matches.group_by("scenario").len().sort("scenario").iter_rows()),
        "floor_s": floor, "ingest_s": ingest_s, "match_s": match_s, "pipeline_s": ingest_s + match_s,
        "ratio_to_floor": (ingest_s + match_s) / floor, "cost_per_row_us": 1e6 * (ingest_s + match_s) / n,
        "peak_rss_bytes": peak, "duckdb_memory_limit": memory_limit(),
        "rematch_s": rematch_s, "rematch_rows_per_s": n / rematch_s, "rematch_ratio_to_floor": rematch_s / floor,
        "rematch_stages": dict(rematch_rec.seconds), "rematch_stage_cpu_s": dict(rematch_rec.cpu_seconds),
        "rematch_cpu_s": rematch_cpu,
        "rematch_nocache_s": rematch_nocache_s, "rematch_nocache_cpu_s": rematch_nocache_cpu,
        "param_rematch_s": param["seconds"], "param_rematch_rows_per_s": n / param["seconds"],
        "param_rematch_ratio_to_floor": param["seconds"] / floor, "param_rematch": param,
        "duration_rematch": duration,
        "floor_cpu_s": floor_cpu, "ingest_cpu_s": ingest_cpu, "match_cpu_s": match_cpu,
        "pipeline_cpu_s": ingest_cpu + match_cpu, "cpu_ratio_to_floor": (ingest_cpu + match_cpu) / floor_cpu,
        "golden": golden_check(db, args.tier, args.write_golden), "engines": engines,
        "stages": {name: {"seconds": s, "rows_per_s": n / s if s > 0 else None, "ratio_to_floor": s / floor,
                          "cpu_seconds": cpus.get(name), "peak_rss_bytes": peaks.get(name, peak)}
                   for name, s in stages.items()},
        "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.machine()}, {multiprocessing.cpu_count()} cores, Python {platform.python_version()}",
    }
    if args.tier == "S" and not args.no_baseline:
        report["baseline"] = run_baseline(db, args.ego)
        report["ratio_to_baseline"] = report["baseline"]["ratio_to_baseline"]
    write_results(args.tier, report, markdown(report))
    return report


if __name__ == "__main__":
    main()
