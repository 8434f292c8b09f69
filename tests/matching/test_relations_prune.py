"""relations holds only the actor kinds some scenario of the run can use (each scenario's `relation_kinds`, every
kind when one leaves it unset; logiq_sql.spec.plan.relation_kinds_csv): the kept rows of a run are relations_of's rows of
those kinds, and a scenario run alone gives the matches, phases, KPIs and coverage it gives beside the others."""

from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql import match
from logiq_sql.spec.plan import ALL_KINDS_CSV, relation_kinds_csv, resolve_scenarios

DATA = Path(__file__).parents[1] / "data"
CYCLIST = "cyclist_close_to_moving_sut"
SCENARIOS = [CYCLIST, "follower_vehicle"]
SETTINGS = {"ego": "every:3", "overrides": {"max_distance_from_cyclist": "8m"}, "keep": True}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, ingested) -> dict[str, Path]:
    """The bundled SUMO junction (cyclists, people and cars) matched with the cyclist and the follower together,
    and a copy matched with the cyclist alone."""
    folder = tmp_path_factory.mktemp("prune")
    both = ingested(folder / "both.duckdb", "sumo", [DATA / "sumo/junction_s1"])
    alone = folder / "alone.duckdb"
    shutil.copy(both, alone)
    match(both, scenarios=SCENARIOS, **SETTINGS)
    said: list[str] = []
    match(alone, scenarios=[CYCLIST], progress=said.append, **SETTINGS)
    assert any("actors of kinds cyclist only" in line for line in said), said
    return {"both": both, "alone": alone}


def _read(db: Path, sql: str) -> pl.DataFrame:
    with duckdb.connect(str(db), read_only=True) as con:
        return con.sql(sql).pl()


def test_the_run_relates_the_kinds_its_scenarios_declare():
    scenarios = {s.name: s for s in resolve_scenarios(None, {})}
    assert relation_kinds_csv([scenarios[CYCLIST]]) == ",cyclist,"
    # a scenario that leaves relation_kinds unset reads every kind (the nearest road user of any kind)
    assert relation_kinds_csv([scenarios[CYCLIST], scenarios["follower_vehicle"]]) == ALL_KINDS_CSV
    assert all(relation_kinds_csv([s]) == ALL_KINDS_CSV for name, s in scenarios.items() if name != CYCLIST)


def test_the_cyclist_alone_gives_its_same_results(runs):
    for table, order in (("matches", "drive_id, ego_id, actor_id, start_frame"),
                         ("match_phases", "match_id, phase_index"), ("kpis", "match_id"),
                         ("coverage_samples", "match_id, item")):
        mine = f"scenario = '{CYCLIST}'"
        sql = f"select * exclude (run_id) from {table} where {mine} order by {order}" if table == "matches" else (
            f"select * from {table} where {mine} order by {order}")
        want, got = _read(runs["both"], sql), _read(runs["alone"], sql)
        if table == "kpis":
            want = want.select(got.columns)  # the run beside the follower has its KPI columns too
        assert want.height > 0, table
        assert got.equals(want), table


def test_the_kept_relations_are_relations_of_of_the_declared_kinds(runs):
    """The kept rows of the cyclist-alone run are exactly relations_of's cyclist rows, ego by ego; the run with the
    follower keeps every kind, so more rows (this comparison can fail)."""
    with duckdb.connect(str(runs["alone"]), read_only=True) as con:
        egos = con.execute("select distinct drive_id, ego_id from ego_lanes order by all").fetchall()
        assert len(egos) >= 5
        compared = 0
        for drive, ego in egos:
            want = con.execute("select * from relations_of($d, $e) where actor_kind = 'cyclist' "
                               "order by actor_id, frame", {"d": drive, "e": ego}).fetchall()
            got = con.execute("select * from relations where drive_id = $d and ego_id = $e order by actor_id, frame",
                              {"d": drive, "e": ego}).fetchall()
            assert got == want, (drive, ego)
            compared += len(want)
        assert compared > 0
    kinds = _read(runs["both"], "select actor_kind, count(*) as n from relations group by all")
    alone = _read(runs["alone"], "select count(*) as n from relations")["n"][0]
    assert set(kinds["actor_kind"]) > {"cyclist"}  # cars and people too
    assert alone == kinds.filter(pl.col("actor_kind") == "cyclist")["n"].sum() < kinds["n"].sum()


def test_relation_kinds_must_be_kinds(tmp_path):
    from logiq_sql.core.errors import ScenarioError
    from logiq_sql.core.paths import data_dir
    from logiq_sql.spec.scenario import load_scenario

    text = (data_dir("scenarios") / f"{CYCLIST}.toml").read_text()
    assert 'relation_kinds = ["cyclist"]' in text
    for bad, says in (('["bicycle"]', "'bicycle' is not an evaluation_object_kind"), ("[]", "non-empty list")):
        (tmp_path / f"{CYCLIST}.toml").write_text(text.replace('relation_kinds = ["cyclist"]', f"relation_kinds = {bad}"))
        with pytest.raises(ScenarioError, match=says):
            load_scenario(CYCLIST, tmp_path)
    # not inherited: a scenario that extends the cyclist's declares its own (unset: every kind)
    (tmp_path / f"{CYCLIST}.toml").write_text(text)
    (tmp_path / "my_cyclist.toml").write_text(text.replace(f'name = "{CYCLIST}"', 'name = "my_cyclist"')
                                              .replace('extends = ["logiq_base_object_scenario"]',
                                                       f'extends = ["{CYCLIST}"]')
                                              .replace('relation_kinds = ["cyclist"]\n', ""))
    assert load_scenario("my_cyclist", tmp_path).relation_kinds is None
