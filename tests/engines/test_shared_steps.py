"""A phase step that two scenarios of a group run with the same values on the group's shared tables is computed
once (runner.shared_phase_steps, Engine.share): sut_cut_out and cut_in_ahead_of_ego both run
phases/ego_on_same_lane.sql. The matches, phases and KPIs are those of each scenario run alone."""

from __future__ import annotations

import duckdb
import polars as pl

from logiq_sql.engines.duckdb_engine import DuckEngine
from logiq_sql.matching.match import match
from logiq_sql.matching.runner import shared_phase_steps
from logiq_sql.spec.plan import parse_ego, resolve_scenarios, run_values
from tests.helpers import Y1, Y2, actor, make_db, times
from tests.matching.test_cut_out import ramp

CUT_IN, CUT_OUT = "cut_in_ahead_of_ego", "sut_cut_out"


def values_of(scenarios):
    return {s.name: run_values(s, parse_ego("every:10"), 200.0) for s in scenarios}


def test_the_built_in_scenarios_share_ego_on_same_lane_only():
    scenarios = resolve_scenarios(None, {})
    values = values_of(scenarios)
    assert {rel for rel, _ in shared_phase_steps(scenarios, values)} == {"phases/ego_on_same_lane.sql"}
    # a value that differs (an override one of them has) makes two steps
    changed = dict(values, sut_cut_out={**values[CUT_OUT], "max_distance_from_sut_in_time_units_s": 4.0})
    assert shared_phase_steps(scenarios, changed) == frozenset()
    # phases that read a table the scenario writes (the left turn's read scenario_frames) are never shared
    (left_turn,) = resolve_scenarios(["unprotected_left_turn_with_yield_and_traffic_light"], {})
    assert shared_phase_steps([left_turn, left_turn], values_of([left_turn])) == frozenset()


def test_scenarios_sharing_a_phase_match_as_each_alone(tmp_path):
    t = times(10.0)
    db = make_db(tmp_path, [
        # d1: the ego leaves the npc's lane (a cut-out); d2: the npc moves into the ego's lane ahead (a cut-in)
        actor("ego", t, 100 + 10 * t, ramp(t, 4.5, Y1, Y2), is_ego=True), actor("npc", t, 130 + 10 * t, Y1),
        actor("ego", t, 100 + 10 * t, Y1, is_ego=True, drive_id="d2"),
        actor("npc", t, 120 + 10 * t, ramp(t, 3.0, Y2, Y1, 3.0), drive_id="d2"),
    ])

    def outputs(result, name):
        ids = result.matches.filter(pl.col("scenario") == name)["match_id"]
        return (result.matches.filter(pl.col("scenario") == name).drop("run_id").sort("match_id"),
                result.match_phases.filter(pl.col("match_id").is_in(ids.to_list())).sort("match_id", "phase_index"),
                result.kpis.filter(pl.col("scenario") == name).sort("match_id"))

    together = match(db, scenarios=[CUT_IN, CUT_OUT], force=True)
    batched = match(db, scenarios=[CUT_IN, CUT_OUT], force=True, batch_rows=1)  # a batch per drive
    for name in (CUT_IN, CUT_OUT):
        alone = match(db, scenarios=[name], force=True)
        for run in (together, batched):
            for got, expected in zip(outputs(run, name), outputs(alone, name), strict=True):
                assert got.height > 0
                assert got.equals(expected.select(got.columns)), name


def test_the_engine_computes_a_shared_step_once_and_forgets_it(tmp_path):
    t = times(10.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("npc", t, 130 + 10 * t, Y1)])
    scenarios = resolve_scenarios([CUT_IN, CUT_OUT], {})
    values = values_of(scenarios)
    with duckdb.connect(str(db)) as con:
        con.execute("create temp table run_drives as select drive_id from drive_inputs")
        engine = DuckEngine(con)
        for table, rel in (("egos", "relations/egos.sql"), ("lane_line", "relations/lane_line.sql"),
                           ("lane_neighbours", "relations/lane_neighbours.sql"),
                           ("actor_lanes", "relations/actor_lanes.sql"), ("ego_lanes", "relations/ego_lanes.sql"),
                           ("relations", "relations/relations.sql")):
            engine.materialise(table, rel, values[CUT_IN])
        engine.materialise("alone", "phases/ego_on_same_lane.sql", values[CUT_IN])
        engine.share(shared_phase_steps(scenarios, values))
        engine.materialise("phase_2", "phases/ego_on_same_lane.sql", values[CUT_IN])
        engine.materialise("phase_1", "phases/ego_on_same_lane.sql", values[CUT_OUT])
        engine.materialise("phase_2", "phases/ego_side_of_npc.sql", values[CUT_OUT])  # a view replaced by a table

        def temp_objects():
            return {r[0] for r in con.execute("select table_name from duckdb_tables() where temporary union all "
                                              "select view_name from duckdb_views() where temporary").fetchall()}

        assert {"_shared_step_1", "phase_1", "phase_2"} <= temp_objects() and "_shared_step_2" not in temp_objects()
        for a, b in (("alone", "phase_1"), ("phase_1", "alone")):
            assert con.execute(f"select count(*) from (select * from {a} except all select * from {b})").fetchone() \
                == (0,)
        assert con.execute("select count(*) from phase_1").fetchone()[0] > 0
        engine.release_drives()
        assert not {"_shared_step_1", "phase_1"} & temp_objects()
