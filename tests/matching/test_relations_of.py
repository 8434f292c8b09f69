"""relations_of(drive_id, ego_id), the table macro match creates, gives exactly the rows the matcher's relation
table holds for that ego (kept with match --keep), with the default range and tolerance and with others."""

from __future__ import annotations

from pathlib import Path

import duckdb
import pytest

from logiq_sql import ingest, match

DATA = Path(__file__).parents[1] / "data"


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rel") / "x.duckdb"
    ingest("sumo", [DATA / "sumo/junction_s1"], path)
    ingest("commonroad", [DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"], path)
    return path


def _same_rows(db: Path, macro_args: str = "") -> int:
    with duckdb.connect(str(db), read_only=True) as con:
        egos = con.execute("select distinct drive_id, ego_id from relations order by all").fetchall()
        assert len(egos) >= 5
        compared = 0
        for drive, ego in egos:
            want = con.execute("select * from relations where drive_id = $d and ego_id = $e order by actor_id, frame",
                               {"d": drive, "e": ego}).fetchall()
            got = con.execute(f"select * from relations_of($d, $e{macro_args}) order by actor_id, frame",
                              {"d": drive, "e": ego}).fetchall()
            assert got == want, (drive, ego)
            compared += len(want)
        return compared


def test_relations_of_equals_the_kept_relations(db):
    match(db, scenarios=["follower_vehicle"], ego="every:15", keep=True)
    assert _same_rows(db) > 0


def test_relations_of_with_another_range_and_tolerance(db):
    match(db, scenarios=["follower_vehicle"], ego="every:15", keep=True, relation_range="60m",
          overrides={"lane_calculation_tolerance_length": "0.5m"})
    assert _same_rows(db, ", relation_range_m := 60, lane_tolerance_m := 0.5") > 0


def test_a_different_range_gives_different_rows(db):
    """The comparison above can fail: the default range gives more rows than the kept 60 m relation."""
    with duckdb.connect(str(db), read_only=True) as con:
        drive, ego = con.execute("select drive_id, ego_id from relations group by all "
                                 "order by count(*) desc limit 1").fetchall()[0]
        kept = con.execute("select count(*) from relations where drive_id = $d and ego_id = $e",
                           {"d": drive, "e": ego}).fetchall()[0][0]
        wide = con.execute("select count(*) from relations_of($d, $e)", {"d": drive, "e": ego}).fetchall()[0][0]
    assert wide > kept
