"""The Parquet dataset, the interchange a Spark cluster reads: ``ingest --dataset DIR`` writes the canonical tables
partitioned by drive, file by file; DuckDB matches it (``match --dataset``) as it matches an ingested file. No
Spark needed (the Spark runs over a dataset are in tests/engines/test_spark_cluster.py)."""

from __future__ import annotations

import shutil
from urllib.parse import unquote

import duckdb
from test_spark import DATA, assert_same_outputs

from logiq_sql.cli import EXIT_OK, EXIT_REJECTED, main

NGSIM = DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
SCENE = DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0103.pkl"
MATCH = ["--scenario", "follower_vehicle", "--scenario", "cyclist_close_to_moving_sut", "--ego", "every:4",
         "--set", "max_distance_from_cyclist=6m", "--quiet"]


def test_a_dataset_matches_like_the_file_it_replaces(tmp_path, capsys):
    file = tmp_path / "drives.duckdb"
    assert main(["ingest", "commonroad", str(NGSIM), "--db", str(file), "--quiet"]) == EXIT_OK
    assert main(["ingest", "scenarionet", str(SCENE), "--db", str(file), "--quiet"]) == EXIT_OK
    dataset = tmp_path / "dataset"
    # two ingests into one folder, as two machines would write it
    assert main(["ingest", "commonroad", str(NGSIM), "--dataset", str(dataset), "--quiet"]) == EXIT_OK
    assert main(["ingest", "scenarionet", str(SCENE), "--dataset", str(dataset), "--quiet"]) == EXIT_OK
    drives = sorted(unquote(p.name) for p in (dataset / "tracks").iterdir())  # DuckDB percent-encodes the @
    assert drives == ["drive_id=USA_US101-22_1_T-1@2018b", "drive_id=scene-0103"], drives
    assert all(p.name.startswith("map_id=") for p in (dataset / "lanes").iterdir())

    # the same canonical rows as the file (track_lanes: the localisation, done at ingest)
    with duckdb.connect(str(file), read_only=True) as con:
        for table in ("tracks", "track_lanes", "lanes", "drive_inputs"):
            cols = [c for c in con.table(table).columns]
            expected = sorted(con.sql(f"select {', '.join(cols)} from {table}").fetchall(), key=repr)
            with duckdb.connect() as mem:
                got = sorted(mem.sql(f"select {', '.join(cols)} from read_parquet('{dataset / table}/**/*.parquet', "
                                     "hive_partitioning = true, hive_types_autocast = false)").fetchall(), key=repr)
            assert got == expected, table

    # ingesting a file again replaces its drive: no second copy of its rows
    before = len(list((dataset / "tracks").rglob("*.parquet")))
    assert main(["ingest", "commonroad", str(NGSIM), "--dataset", str(dataset), "--quiet"]) == EXIT_OK
    assert len(list((dataset / "tracks").rglob("*.parquet"))) == before

    out = tmp_path / "out"
    assert main(["match", "--db", str(file), *MATCH]) == EXIT_OK
    assert main(["match", "--dataset", str(dataset), "--out", str(out), *MATCH]) == EXIT_OK
    assert_same_outputs(file, out / "logiq.duckdb")
    with duckdb.connect(str(out / "logiq.duckdb"), read_only=True) as con:  # an analyst's file over the dataset
        kinds = dict(con.execute("select table_name, table_type from information_schema.tables "
                                 "where table_name in ('tracks', 'matches')").fetchall())
        assert kinds == {"tracks": "VIEW", "matches": "BASE TABLE"}, kinds
        assert con.execute("select count(*) from matches").fetchone()[0] > 0
    capsys.readouterr()
    # incremental, as on a file: a second run over the same dataset and results file has nothing to do
    assert main(["match", "--dataset", str(dataset), "--out", str(out), *MATCH]) == EXIT_OK
    assert "already up to date" in capsys.readouterr().out
    assert_same_outputs(file, out / "logiq.duckdb")


def test_a_drive_id_from_two_files_is_kept_once_and_the_second_accounted_for(tmp_path):
    dataset = tmp_path / "dataset"
    copy = tmp_path / "elsewhere" / NGSIM.name
    copy.parent.mkdir()
    shutil.copy(NGSIM, copy)
    assert main(["ingest", "commonroad", str(NGSIM), "--dataset", str(dataset), "--quiet"]) == EXIT_OK
    assert main(["ingest", "commonroad", str(copy), "--dataset", str(dataset), "--quiet"]) == EXIT_REJECTED
    with duckdb.connect() as con:
        rows = con.sql(f"select drive_id, status, source_path, reject_reason from read_parquet("
                       f"'{dataset}/drive_inputs/**/*.parquet', hive_partitioning = true, "
                       "hive_types_autocast = false) order by status").fetchall()
    assert [r[:3] for r in rows] == [("USA_US101-22_1_T-1@2018b", "ingested", str(NGSIM)),
                                     (f"USA_US101-22_1_T-1@2018b ({copy})", "rejected", str(copy))], rows
    assert "already in the dataset" in rows[1][3]
    assert len(list((dataset / "tracks").iterdir())) == 1
