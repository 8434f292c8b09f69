"""`pip install .` gives the logiq-sql command with the SQL and scenario files inside the wheel, and the README's
commands work from it outside the checkout."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DRIVE = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"


@pytest.mark.slow
def test_the_wheel_carries_its_sql_and_runs_outside_the_checkout(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(tmp_path / "dist")],
                   check=True, cwd=tmp_path)
    (wheel,) = (tmp_path / "dist").glob("logiq_sql-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder, suffix in (("queries", ".sql"), ("scenarios", ".toml")):
        shipped = {f"logiq_sql/{p.relative_to(ROOT)}" for p in (ROOT / folder).rglob(f"*{suffix}")}
        assert shipped and shipped <= names, f"{folder}/ missing from the wheel: {sorted(shipped - names)[:3]}"
    assert any(n.endswith("entry_points.txt") for n in names)

    # install the wheel alone into a folder; its dependencies come from this environment
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                   check=True)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}

    def cli(*args: str) -> str:
        run = subprocess.run([str(site / "bin/logiq-sql"), *args], check=False, cwd=elsewhere, env=env,
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        return run.stdout

    where = subprocess.run([sys.executable, "-c", "import logiq_sql; print(logiq_sql.__file__)"], cwd=elsewhere,
                           env=env, capture_output=True, text=True, check=True).stdout
    assert where.startswith(str(site))  # the installed copy, not the checkout
    assert "follower_vehicle  (scenario; extends logiq_base_lane_following_scenario" in cli("scenarios")
    version = tomllib.loads((ROOT / "scenarios/follower_vehicle.toml").read_text())["version"]
    assert f"-- scenario follower_vehicle (version {version})" in cli("render", "follower_vehicle")
    # the README's quickstart, with a drive from the checkout's data
    assert "1 drive(s) ingested, 0 rejected" in cli("ingest", "commonroad", str(DRIVE), "--db", "drives.duckdb")
    assert "follower_vehicle:" in cli("match", "--db", "drives.duckdb", "--scenario", "follower_vehicle",
                                      "--ego", "every:10", "--quiet")
    assert "follower_vehicle" in cli("query", "--db", "drives.duckdb", "select scenario, count(*) from matches "
                                     "group by 1")
    cli("report", "--db", "drives.duckdb", "--out", "report.html")
    assert (elsewhere / "report.html").stat().st_size > 10_000
