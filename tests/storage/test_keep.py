"""match stores the intermediate tables relations, passages and encroachments only with keep (match --keep);
ego_lanes always. A run without keep removes what an earlier kept run left for its drives."""

from __future__ import annotations

from pathlib import Path

import duckdb

from logiq_sql import match

JUNCTION = Path(__file__).parents[1] / "data/sumo/junction_s1"
LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"


def _counts(db: Path) -> dict[str, int | None]:
    with duckdb.connect(str(db), read_only=True) as con:
        have = {r[0] for r in con.execute("select table_name from duckdb_tables()").fetchall()}
        return {t: con.execute(f"select count(*) from {t}").fetchall()[0][0] if t in have else None
                for t in ("relations", "ego_lanes", "passages", "encroachments")}


def test_intermediate_tables_are_stored_only_with_keep(tmp_path, ingested):
    db = ingested(tmp_path / "x.duckdb", "sumo", [JUNCTION])
    match(db, scenarios=[LEFT_TURN], ego="every:5")
    plain = _counts(db)
    assert plain["ego_lanes"] > 0
    assert plain["relations"] is None and plain["passages"] is None and plain["encroachments"] is None
    match(db, scenarios=[LEFT_TURN], ego="every:5", keep=True, force=True)
    kept = _counts(db)
    assert kept["relations"] > 0 and kept["passages"] > 0 and kept["encroachments"] > 0
    assert kept["ego_lanes"] == plain["ego_lanes"]
    with duckdb.connect(str(db), read_only=True) as con:
        # a filter sees every row of a kept table created by this run (DuckDB 2.0 skipped them all when the
        # table was created and filled in one transaction)
        assert con.execute("select count(*) from relations where drive_id = 'junction_s1'").fetchall()[0][0] \
            == kept["relations"]
    # a later run without keep leaves no rows of the earlier kept run for these drives
    match(db, scenarios=[LEFT_TURN], ego="every:5", force=True)
    assert _counts(db) == {"relations": 0, "ego_lanes": plain["ego_lanes"], "passages": 0, "encroachments": 0}


def test_the_cli_passes_keep(tmp_path, capsys, ingested):
    from logiq_sql.cli import main

    db = ingested(tmp_path / "x.duckdb", "sumo", [JUNCTION])
    assert main(["match", "--db", str(db), "--scenario", LEFT_TURN, "--ego", "every:5", "--keep", "--quiet"]) == 0
    assert _counts(db)["relations"] > 0
