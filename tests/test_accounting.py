"""Every drive that goes in comes out in `drives`: matched, no match, or rejected with the reason."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import polars as pl

from logiq_sql import ingest, match

DATA = Path(__file__).parent / "data"


def test_a_corrupt_file_is_rejected_and_the_others_still_match(tmp_path):
    good = DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(good, folder / good.name)
    raw = gzip.decompress(good.read_bytes())
    (folder / "USA_broken_T-1.xml.gz").write_bytes(gzip.compress(raw)[:5000])  # truncated
    db = tmp_path / "x.duckdb"
    summary = ingest("commonroad", [folder], db)
    assert (summary.drives, summary.rejected) == (1, 1)
    result = match(db, scenarios=["follower_vehicle"], ego="every:10")
    drives = {r["drive_id"]: r for r in result.drives.iter_rows(named=True)}
    assert drives["USA_US101-22_1_T-1@2018b"]["status"] == "matched"
    assert drives["USA_broken_T-1"]["status"] == "rejected"
    assert "USA_broken_T-1.xml.gz" in drives["USA_broken_T-1"]["reject_reason"]
    assert drives["USA_US101-22_1_T-1@2018b"]["rows_read"] == 5538


def test_a_drive_with_two_egos_is_rejected_with_the_reason(tmp_path):
    rows = pl.DataFrame({"drive_id": ["a", "a", "b"], "actor_id": ["1", "2", "1"], "kind": ["vehicle"] * 3,
                         "is_ego": [True, True, True], "t_s": [0.0, 0.0, 0.0], "x_m": [0.0, 10.0, 0.0],
                         "y_m": [0.0, 0.0, 0.0]})
    rows.write_parquet(tmp_path / "tracks.parquet")
    db = tmp_path / "x.duckdb"
    ingest("parquet", [tmp_path / "tracks.parquet"], db)
    drives = {r["drive_id"]: r for r in match(db).drives.iter_rows(named=True)}
    assert drives["a"]["status"] == "rejected"
    assert drives["a"]["reject_reason"] == (f"{tmp_path / 'tracks.parquet'}: drive 'a' has 2 actors with is_ego = "
                                            "true (1, 2); a drive has at most one recorded ego.")
    assert drives["b"]["status"] == "no_match"


def test_reingesting_a_drive_replaces_it(tmp_path):
    good = DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
    db = tmp_path / "x.duckdb"
    ingest("commonroad", [good], db)
    ingest("commonroad", [good], db)
    drives = match(db, scenarios=["follower_vehicle"], ego="671").drives
    assert drives.height == 1 and drives["rows_read"].to_list() == [5538]
