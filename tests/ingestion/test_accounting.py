"""Every drive that goes in comes out in `drives`: matched, no match, or rejected with the reason."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql import ingest, match

DATA = Path(__file__).parents[1] / "data"


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


def test_every_real_drive_is_accounted_for_and_the_counts_add_up(tmp_path):
    from logiq_sql.ingestion.ingest import expand
    from logiq_sql.spec.scenario import list_scenarios

    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "USA_cut_T-1.xml.gz").write_bytes((DATA / "commonroad_ngsim/scenarios_2018b/"
                                                  "USA_US101-22_1_T-1.xml.gz").read_bytes()[:3000])
    inputs = [("commonroad", [DATA / "commonroad_ngsim", broken]),
              ("scenarionet", [DATA / "nuscenes_mini_scenarionet"]), ("av2", [DATA / "av2"])]
    db = tmp_path / "x.duckdb"
    files = 0
    for fmt, paths in inputs:
        files += len(expand(fmt, paths))
        ingest(fmt, paths, db)
    result = match(db, ego="every:5")
    drives = result.drives
    assert files == drives.height == 92 + 1 + 4 + 5  # NGSIM scenes, the broken file, nuScenes scenes, AV2 logs

    con = duckdb.connect(str(db), read_only=True)
    kept = con.sql("select drive_id, count(*) as kept from tracks group by drive_id").pl()
    rows = drives.join(kept, on="drive_id", how="left").with_columns(pl.col("kept").fill_null(0))
    assert (rows["rows_read"] == rows["kept"] + rows["rows_rejected"]).all()
    assert rows["rows_read"].sum() > 250_000
    (bad,) = rows.filter(pl.col("status") == "rejected").iter_rows(named=True)
    assert bad["drive_id"] == "USA_cut_T-1" and str(broken / "USA_cut_T-1.xml.gz") in bad["reject_reason"]
    assert rows.filter(pl.col("rows_rejected") > 0)["reject_reason"].null_count() == 0  # a reason for every loss

    scenarios = sorted(s.name for s in list_scenarios())
    per = con.sql("select * from drive_scenarios").pl()
    assert per.height == drives.height * len(scenarios)
    assert set(per["status"]) <= {"matched", "no_match", "no_ego", "rejected"}
    assert per.filter(pl.col("drive_id") == "USA_cut_T-1")["status"].to_list() == ["rejected"] * len(scenarios)
    counted = per.group_by("scenario").agg(pl.col("matches").sum()).sort("scenario")
    stored = con.sql("select scenario, count(*) as matches from matches group by scenario").pl()
    runs = con.sql("select scenario, matches from match_runs").pl()
    for s in scenarios:
        n = counted.filter(pl.col("scenario") == s)["matches"].item()
        assert n == (stored.filter(pl.col("scenario") == s)["matches"].sum()) == runs.filter(
            pl.col("scenario") == s)["matches"].item()
    assert drives["matches"].sum() == result.matches.height > 0
    assert (per.filter(pl.col("status") == "matched")["matches"] > 0).all()
    assert (per.filter(pl.col("status") != "matched")["matches"] == 0).all()
