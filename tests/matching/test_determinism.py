"""Determinism: the same drives and parameters give byte-identical Parquet outputs, whatever DuckDB's thread
count and the order in which the drives were ingested.

Excluded by design: run_id (in match_runs, matches and drive_scenarios) and match_runs.started_at, which say
which run made a row and when; those tables are compared without them, every other file byte for byte.
"""

from __future__ import annotations

from pathlib import Path

import polars as pl

from logiq_sql import ingest, match
from logiq_sql.matching.match import EXPORTED
from logiq_sql.storage.db import THREADS_ENV

DATA = Path(__file__).parents[1] / "data"
# every NGSIM 2018b scene: with fewer rows DuckDB does not spread the KPI aggregates over threads, and an
# order-dependent float sum would go unnoticed (it did with 5 scenes, not with these 87)
NGSIM = sorted((DATA / "commonroad_ngsim/scenarios_2018b").glob("*.xml.gz"))
INPUTS = [("commonroad", NGSIM), ("scenarionet", [DATA / "nuscenes_mini_scenarionet"]),
          ("commonroad", sorted((DATA / "commonroad_ngsim/scenarios_2020a_with_traffic_lights").glob("*.xml*")))]
RUN_SPECIFIC = ("run_id", "started_at")


def run_once(folder: Path, monkeypatch, threads: int, reverse: bool) -> Path:
    monkeypatch.setenv(THREADS_ENV, str(threads))
    db = folder / "x.duckdb"
    for fmt, paths in (reversed(INPUTS) if reverse else INPUTS):
        ingest(fmt, list(reversed(paths)) if reverse else paths, db)
    match(db, ego="every:3", out=folder / "out")
    return folder / "out"


def test_outputs_are_byte_identical_across_thread_counts(tmp_path, monkeypatch):
    one = run_once(tmp_path / "one", monkeypatch, threads=1, reverse=False)
    two = run_once(tmp_path / "two", monkeypatch, threads=2, reverse=True)
    assert sorted(p.name for p in one.iterdir()) == sorted(f"{t}.parquet" for t in EXPORTED)
    matches = pl.read_parquet(one / "matches.parquet")
    assert matches.height > 50 and matches["scenario"].n_unique() >= 2  # something to compare
    for table in EXPORTED:
        name = f"{table}.parquet"
        a, b = (pl.read_parquet(d / name) for d in (one, two))
        specific = [c for c in RUN_SPECIFIC if c in a.columns]
        if specific:
            assert a.drop(specific).equals(b.drop(specific)), name
            assert a["run_id"].unique().to_list() != b["run_id"].unique().to_list()  # they do say which run
        else:
            assert (one / name).read_bytes() == (two / name).read_bytes(), name
