"""Interrupted runs: a real `logiq-sql ingest` / `logiq-sql match` killed with SIGKILL mid-way leaves the DuckDB
file consistent (every write is one transaction), and rerunning completes it without duplicates, equal to a run
that was never interrupted."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import duckdb
import polars as pl
import pytest

ROOT = Path(__file__).parents[2]
DATA = ROOT / "tests/data"
NGSIM = DATA / "commonroad_ngsim/scenarios_2018b"
SCENES = sorted(NGSIM.glob("USA_US101-*.xml.gz"))  # 26 scenes with followers and cut-outs
# small batches, so that a run killed half-way has already committed some of them
INGEST = ("import sys, logiq_sql.ingestion.ingest as i; i.BATCH_ROWS = 5000; from logiq_sql.cli import main; "
          "sys.exit(main(sys.argv[1:]))")
MATCH = ["-m", "logiq_sql.cli", "match", "--ego", "every:4"]


def cli(args: list[str], kill_after: str | None = None) -> tuple[int, str]:
    """Run the command; unless ``kill_after`` is None, SIGKILL it as soon as a progress line contains that text.
    Returns the exit code (negative: killed) and the progress it printed."""
    proc = subprocess.Popen([sys.executable, *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if kill_after is not None and kill_after in line:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=600)
    proc.stderr.close()
    return proc.returncode, "".join(seen)


def table(db: Path, sql: str) -> pl.DataFrame:
    con = duckdb.connect(str(db), read_only=True)
    try:
        return con.sql(sql).pl()
    finally:
        con.close()


def count(db: Path, sql: str) -> int:
    return table(db, sql).item()


def assert_consistent(db: Path) -> None:
    """No orphans, no duplicates, every drive's rows as its drive_inputs row says."""
    checks = {
        "duplicate drive_inputs rows": "select count(*) - count(distinct drive_id) from drive_inputs",
        "duplicate track rows": "select count(*) from (select drive_id, actor_id, frame from tracks "
                                "group by all having count(*) > 1)",
        "tracks of no accepted drive": "select count(*) from tracks where drive_id not in "
                                       "(select drive_id from drive_inputs where status = 'ingested')",
        "track_lanes of no drive": "select count(*) from track_lanes where drive_id not in "
                                   "(select drive_id from drive_inputs where status = 'ingested')",
        "drives whose rows do not add up": """
            select count(*) from drive_inputs d
            left join (select drive_id, count(*) as n from tracks group by drive_id) t using (drive_id)
            where d.rows_read != coalesce(t.n, 0) + d.rows_rejected""",
        "duplicate matches": "select count(*) - count(distinct match_id) from matches",
        "matches of no drive": "select count(*) from matches where drive_id not in (select drive_id from drive_inputs)",
        "orphan match_phases": "select count(*) from match_phases where match_id not in (select match_id from matches)",
        "orphan kpis": "select count(*) from kpis where match_id not in (select match_id from matches)",
        "orphan coverage_samples": "select count(*) from coverage_samples where match_id not in "
                                   "(select match_id from matches)",
        "matches without kpis": "select count(*) from matches where match_id not in (select match_id from kpis)",
        "matches without phases": "select count(*) from matches where match_id not in "
                                  "(select match_id from match_phases)",
        "duplicate drive_scenarios": "select count(*) from (select drive_id, scenario from drive_scenarios "
                                     "group by all having count(*) > 1)",
        "drive_scenarios counts off": """
            select count(*) from drive_scenarios s
            left join (select drive_id, scenario, count(*) as n from matches group by all) m using (drive_id, scenario)
            where s.matches != coalesce(m.n, 0)""",
    }
    if "kpis" not in table(db, "select table_name from duckdb_tables()")["table_name"].to_list():
        checks = {k: v for k, v in checks.items() if "kpis" not in v}  # made by the first match run
    problems = {name: count(db, sql) for name, sql in checks.items()}
    assert problems == dict.fromkeys(checks, 0)


def snapshot(db: Path) -> dict[str, pl.DataFrame]:
    """The file's content, in a fixed order, without what says when a run happened."""
    order = {"drive_inputs": "drive_id", "tracks": "drive_id, actor_id, frame",
             "track_lanes": "drive_id, actor_id, frame, lane_id", "matches": "match_id",
             "match_phases": "match_id, phase_index", "kpis": "match_id", "drive_scenarios": "drive_id, scenario",
             "coverage": "scenario, item, bucket"}
    frames = {t: table(db, f"select * from {t} order by {o}") for t, o in order.items()}
    return {t: f.drop([c for c in ("run_id", "started_at") if c in f.columns]) for t, f in frames.items()}


def assert_same(a: dict[str, pl.DataFrame], b: dict[str, pl.DataFrame]) -> None:
    for name, frame in a.items():
        assert frame.equals(b[name]), name


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The scenes ingested and matched without interruption."""
    db = tmp_path_factory.mktemp("reference") / "x.duckdb"
    assert cli(["-c", INGEST, "ingest", "commonroad", *map(str, SCENES), "--db", str(db)])[0] == 0
    assert cli([*MATCH, "--db", str(db)])[0] == 0
    return db


def test_a_killed_ingest_leaves_whole_drives_and_a_rerun_completes_it(tmp_path, reference):
    db = tmp_path / "x.duckdb"
    code, progress = cli(["-c", INGEST, "ingest", "commonroad", *map(str, SCENES), "--db", str(db)],
                         kill_after=f"[{len(SCENES) * 2 // 3}/{len(SCENES)}]")
    assert code == -signal.SIGKILL
    assert f"[{len(SCENES)}/{len(SCENES)}]" not in progress
    assert not db.exists()  # nothing published: readers see no half-ingested file
    work = db.with_name(db.name + ".writing")  # the run's own copy, consistent at its last commit
    assert_consistent(work)
    written = count(work, "select count(*) from drive_inputs")
    assert 0 < written < len(SCENES)  # killed with some batches committed and the rest not written
    code, progress = cli(["-c", INGEST, "ingest", "commonroad", *map(str, SCENES), "--db", str(db)])
    assert code == 0 and "taking up the unpublished work" in progress
    assert cli([*MATCH, "--db", str(db)])[0] == 0
    assert_consistent(db)
    assert_same(snapshot(db), snapshot(reference))


# killed at its first progress line, once the relations are made, and once follower_vehicle (the one scenario the
# new parameter reruns) has its matches, which is just before they are committed
@pytest.mark.parametrize("kill_after", ["", "relations:", "follower_vehicle:"])
def test_a_killed_match_keeps_the_previous_results_and_a_rerun_completes_it(tmp_path, reference, kill_after):
    db = tmp_path / "x.duckdb"
    shutil.copy(reference, db)
    before = snapshot(db)
    # a run with another parameter would replace every follower match: killed, it must replace none or all
    other = [*MATCH, "--db", str(db), "--set", "min_scenario_duration=2s"]
    code, _ = cli(other, kill_after=kill_after)
    assert code == -signal.SIGKILL
    assert_consistent(db)
    after_kill = snapshot(db)
    finished = tmp_path / "finished.duckdb"
    shutil.copy(reference, finished)
    assert cli([*other[:-4], "--db", str(finished), *other[-2:]])[0] == 0
    if not after_kill["matches"].equals(before["matches"]):  # killed after the commit: the whole new result
        assert_same(after_kill, snapshot(finished))
    assert cli(other)[0] == 0  # the rerun
    assert_consistent(db)
    assert_same(snapshot(db), snapshot(finished))
    assert snapshot(db)["matches"].height < before["matches"].height  # 2 s drops some 1 s followers
