"""Integer keys assigned at ingest (schema.TRACK_KEYS): each drive's digest of its drive_id, each actor's rank in
actor_id order, each row's rank in (actor_id, frame) order, the rows stored in that order; track_lanes carries
the keys of its track row; a file written before the keys existed gets them when it is opened."""

from __future__ import annotations

import duckdb

from logiq_sql.core import schema
from logiq_sql.storage import db
from tests.helpers import Y1, Y2, actor, make_db, times

T = times(3)


def drives(tmp_path):
    # actor ids whose string order is not the order of their numbers, and rows given out of order
    actors = [actor(a, T, x0 + 10 * T, y, drive_id=d)
              for d in ("d2", "d1") for a, x0, y in (("10", 100, Y1), ("9", 80, Y2), ("ego", 60, Y1))]
    return make_db(tmp_path, [a.reverse() for a in actors])


def expected_keys(con: duckdb.DuckDBPyConnection, table: str) -> str:
    """The keys as the rows' own ids give them, next to the stored ones: rows where they differ."""
    return f"""
        select count(*) from (
            select drive_key, actor_key, row_key,
                dense_rank() over (partition by drive_id order by actor_id) as want_actor,
                dense_rank() over (partition by drive_id order by actor_id, frame) as want_row
            from {table}
        ) where actor_key <> want_actor or row_key <> want_row or actor_key is null or row_key is null"""


def test_keys_follow_the_ids_and_rows_are_stored_in_their_order(tmp_path):
    path = drives(tmp_path)
    with duckdb.connect(str(path), read_only=True) as con:
        keys = dict(con.execute("select drive_id, drive_key from drive_inputs").fetchall())
        assert keys == {d: schema.drive_key(d) for d in ("d1", "d2")}
        assert con.execute("select count(*) from tracks as t inner join drive_inputs as d "
                           "on t.drive_id = d.drive_id and t.drive_key = d.drive_key").fetchone()[0] == 6 * len(T)
        assert con.execute(expected_keys(con, "tracks")).fetchone()[0] == 0
        assert con.execute("select count(distinct (drive_key, row_key)) from tracks").fetchone()[0] == 6 * len(T)
        assert con.execute(expected_keys(con, "track_lanes")).fetchone()[0] == 0
        for table in ("tracks", "track_lanes"):
            stored = con.execute(f"select drive_key, row_key from {table} order by rowid").fetchall()
            runs = [k for i, (k, _) in enumerate(stored) if i == 0 or stored[i - 1][0] != k]
            assert len(runs) == 2, f"{table}: each drive's rows together"
            assert stored == sorted(stored, key=lambda r: (runs.index(r[0]), r[1])), f"{table}: in row_key order"


def test_a_file_without_keys_gets_them_when_opened(tmp_path):
    path = drives(tmp_path)
    with duckdb.connect(str(path)) as con:
        want = con.sql("select drive_id, actor_id, frame, drive_key, actor_key, row_key from tracks "
                           "order by all").pl()
        for table in ("drive_inputs", "tracks", "track_lanes"):
            con.execute(f"update {table} set drive_key = null")
        con.execute("update tracks set actor_key = null, row_key = null")
        con.execute("update track_lanes set actor_key = null, row_key = null")
    con = db.connect(path)
    try:
        got = con.sql("select drive_id, actor_id, frame, drive_key, actor_key, row_key from tracks "
                          "order by all").pl()
        assert got.equals(want)
        assert con.execute(expected_keys(con, "track_lanes")).fetchone()[0] == 0
        assert con.execute("select count(*) from track_lanes where drive_key is null").fetchone()[0] == 0
    finally:
        con.close()

