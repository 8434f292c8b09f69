"""For schedulers: progress on stderr, a summary on stdout, --quiet, and exit codes to act on."""

from __future__ import annotations

import gzip
import shutil
import subprocess
import sys
from pathlib import Path

from logiq_sql.cli import main

ROOT = Path(__file__).resolve().parents[2]
GOOD = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"


def folder_with_a_broken_file(tmp_path: Path) -> Path:
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(GOOD, folder / GOOD.name)
    (folder / "USA_broken_T-1.xml.gz").write_bytes(gzip.compress(gzip.decompress(GOOD.read_bytes()))[:5000])
    return folder


def test_ingest_with_rejected_drives_exits_3_with_progress_and_summary(tmp_path, capsys):
    folder, db = folder_with_a_broken_file(tmp_path), str(tmp_path / "x.duckdb")
    assert main(["ingest", "commonroad", str(folder), "--db", db]) == 3
    out, err = capsys.readouterr()
    assert err.splitlines()[0] == "[1/2] USA_US101-22_1_T-1.xml.gz: 1 drive(s)"
    assert err.splitlines()[1].startswith("[2/2] USA_broken_T-1.xml.gz: rejected: ")
    assert f"{db}: 1 drive(s) ingested, 1 rejected" in out
    assert "1 drive(s) rejected, each with its reason" in out
    # --quiet: no progress, the same summary and exit code
    assert main(["ingest", "commonroad", str(folder), "--db", db, "--quiet"]) == 3
    out, err = capsys.readouterr()
    assert err == "" and f"{db}: 1 drive(s) ingested, 1 rejected" in out


def test_match_shows_progress_then_skips_what_is_up_to_date(tmp_path, capsys):
    db = str(tmp_path / "x.duckdb")
    assert main(["ingest", "commonroad", str(GOOD), "--db", db, "--quiet"]) == 0
    capsys.readouterr()
    assert main(["match", "--db", db, "--scenario", "follower_vehicle", "--scenario", "sut_cut_out"]) == 0
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert lines[0] == "[1/1] 1 drive(s): follower_vehicle, sut_cut_out"
    assert lines[1].startswith("  relations: ") and lines[2].startswith("  follower_vehicle: ")
    assert out.startswith("drives: 1 (matched 1)")
    assert main(["match", "--db", db, "--scenario", "follower_vehicle", "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert out.startswith("already up to date (same scenario version, parameters, ego and range; --force reruns): "
                          "follower_vehicle 1 drive(s)\ndrives: 1 (matched 1)")
    assert main(["match", "--db", db, "--scenario", "follower_vehicle", "--force", "--quiet"]) == 0
    assert "already up to date" not in capsys.readouterr().out


def test_bad_input_exits_2_and_names_the_fix(tmp_path, capsys):
    db = str(tmp_path / "x.duckdb")
    assert main(["ingest", "commonroad", str(GOOD), "--db", db, "--quiet"]) == 0
    capsys.readouterr()
    assert main(["match", "--db", db, "--scenario", "follower_vehicle", "--set", "same_road_limit=5"]) == 2
    assert "same_road_limit" in capsys.readouterr().err
    assert main(["report", "--db", str(tmp_path / "missing.duckdb"), "--out", str(tmp_path / "r.html")]) == 2
    assert "no such file" in capsys.readouterr().err
    # ingested, never matched: the report says what to run first (it once died on a missing kpis table)
    assert main(["report", "--db", db, "--out", str(tmp_path / "r.html")]) == 2
    assert f"no match run recorded yet (kpis missing): run `logiq-sql match --db {db}` first" in capsys.readouterr().err


def test_an_unexpected_failure_exits_1(tmp_path):
    db = tmp_path / "x.duckdb"
    assert main(["ingest", "commonroad", str(GOOD), "--db", str(db), "--quiet"]) == 0
    assert main(["match", "--db", str(db), "--scenario", "follower_vehicle", "--quiet"]) == 0
    # the output folder cannot be created: an environment failure, not bad input
    run = subprocess.run([sys.executable, "-m", "logiq_sql.cli", "report", "--db", str(db), "--out",
                          "/proc/no/report.html"], check=False, capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 1
    assert "Traceback" in run.stderr
