"""Each track row's best lane, marked at ingest (track_lanes.best_lane, schema.BEST_LANE): the same lane DuckDB ranks
first over the row's lanes (within 90 degrees of its heading; by distance, then alignment, then lane_id), on every
bundled map; a file written before the mark gets it when opened; a dataset without the column is refused by name."""

from __future__ import annotations

from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest

from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.localise import _best_lanes
from logiq_sql.matching.explain import explain
from logiq_sql.storage import dataset, db
from tests.helpers import EVERY_MAP

# the rows' lanes ranked by DuckDB's own sort: the independent reading of which lane is best
RANKED = """
    select drive_key, row_key, lane_id, best_lane,
        abs(heading_diff_rad) < pi() / 2 and row_number() over (
            partition by drive_key, row_key, abs(heading_diff_rad) < pi() / 2
            order by dist_m, abs(heading_diff_rad), lane_id) = 1 as ranked_first
    from track_lanes"""


@pytest.fixture(scope="module")
def drives(tmp_path_factory, ingested) -> Path:
    return ingested.steps(tmp_path_factory.mktemp("best_lane") / "x.duckdb", *EVERY_MAP)


def test_the_marked_lane_is_the_one_duckdb_ranks_first_on_every_map(drives):
    with duckdb.connect(str(drives), read_only=True) as con:
        per_map = con.execute(f"""
            select d.map_id, count(*) as pairs, count(*) filter (where r.best_lane) as marked,
                count(*) filter (where r.best_lane is distinct from r.ranked_first) as differ,
                count(distinct (r.drive_key, r.row_key)) filter (where r.ranked_first) as rows_in_a_lane
            from ({RANKED}) as r inner join drive_inputs as d using (drive_key)
            group by d.map_id order by d.map_id""").fetchall()
        assert len(per_map) >= 4, per_map
        for map_id, pairs, marked, differ, rows_in_a_lane in per_map:
            assert differ == 0, f"{map_id}: {differ} of {pairs} pairs marked otherwise than DuckDB ranks them"
            assert 0 < marked == rows_in_a_lane < pairs, (map_id, pairs, marked, rows_in_a_lane)
        # ties on distance are common (0 inside overlapping lanes): the other keys decide there
        (ties,) = con.execute("""
            select count(*) from (select drive_key, row_key from track_lanes
                                  where dist_m = 0 and abs(heading_diff_rad) < pi() / 2
                                  group by all having count(*) > 1)""").fetchone()
        assert ties > 0


def test_ties_are_broken_as_duckdb_breaks_them():
    # the bundled maps seldom tie on both distance and alignment: pairs drawn from a few values tie on every key
    rng = np.random.default_rng(7)
    row = np.sort(rng.integers(0, 2_000, 20_000))
    rank = rng.permutation(20_000).astype(np.int64)
    dist = rng.choice([0.0, 0.0, 0.5, 1.0], 20_000)
    diff = rng.choice([0.1, -0.1, 0.2, 1.5, -1.6, 2.0, np.nan], 20_000)
    pairs = pl.DataFrame({"row": row, "rank": rank, "dist": dist, "diff": diff,
                          "best": _best_lanes(row, rank, dist, diff)}).fill_nan(None)
    with duckdb.connect() as con:
        (differ,) = con.execute("""
            select count(*) from (
                select best, coalesce(abs(diff) < pi() / 2 and row_number() over (
                    partition by row, coalesce(abs(diff) < pi() / 2, false) order by dist, abs(diff), rank) = 1,
                    false) as first
                from pairs)
            where best <> first""").fetchone()
    assert differ == 0
    assert 0 < pairs["best"].sum() < pairs["row"].n_unique()  # some rows have no lane within 90 degrees


def test_a_file_written_before_the_mark_gets_it_when_opened(drives, tmp_path):
    copy = tmp_path / "old.duckdb"
    copy.write_bytes(drives.read_bytes())
    with duckdb.connect(str(copy)) as con:
        want = con.sql("select drive_key, row_key, lane_id, best_lane from track_lanes order by all").pl()
        con.execute("update track_lanes set best_lane = null")
    con = db.connect(copy)
    try:
        got = con.sql("select drive_key, row_key, lane_id, best_lane from track_lanes order by all").pl()
    finally:
        con.close()
    assert got.equals(want)


def test_a_dataset_without_the_mark_is_refused_by_name(drives, tmp_path):
    folder = tmp_path / "dataset"
    with duckdb.connect(str(drives), read_only=True) as con:
        dataset.write(con, folder, "part-a")
        # as an earlier logiq_sql wrote it: track_lanes without best_lane
        for part in (folder / "track_lanes").rglob("*.parquet"):
            con.execute(f"copy (select * exclude (best_lane) from read_parquet('{part}')) to '{part}.old' "
                        "(format parquet)")
            part.unlink()
            Path(f"{part}.old").rename(part)
    with duckdb.connect() as con, pytest.raises(InputError, match=r"track_lanes has no column best_lane.*ingest"):
        dataset.attach(con, folder)


def test_explain_on_a_file_without_the_mark_names_the_fix(drives, tmp_path):
    # read-only, explain cannot add the column: it says which run does, and works once one has
    old = tmp_path / "old.duckdb"
    old.write_bytes(drives.read_bytes())
    with duckdb.connect(str(old)) as con:
        con.execute("alter table track_lanes drop column best_lane")
        drive, ego = con.execute("select drive_id, actor_id from tracks where drive_id like 'USA%' limit 1").fetchone()
    with pytest.raises(InputError, match=r"no column track_lanes\.best_lane\. Fix: .*logiq-sql match --db"):
        explain(old, "follower_vehicle", drive, ego)
    db.connect(old).close()  # what a run that writes the file does first
    assert explain(old, "follower_vehicle", drive, ego) is not None
