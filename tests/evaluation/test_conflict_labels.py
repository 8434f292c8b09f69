"""The left turn's second labeller (logiq_sql/evaluation/conflict_labels.py) on the bundled SUMO junction run,
checked against the run's own records read here independently (tests/evaluation/test_labels.py's FCD offsets and the
tls_states file), and the disagreement report against the phase labeller."""

from __future__ import annotations

import polars as pl
from test_labels import JUNCTION, left_turn_label_rows, needs_fixtures

from logiq_sql.evaluation.conflict_labels import compare, label_conflicts, main


@needs_fixtures
def test_each_label_is_a_wait_on_green_for_a_car_that_crossed_first():
    labels = label_conflicts(JUNCTION)
    assert labels.height >= 20 and labels["source"].str.starts_with("conflict:").all()
    rows, _, at_start = left_turn_label_rows(labels)
    assert at_start.height == labels.height
    # a left-turner standing on green within 10 m of its stop line (front), a vehicle from another edge coming
    assert at_start["e_dir"].is_in(["l", "L"]).all() and (at_start["e_speed_mps"] <= 2 / 3.6 + 1e-9).all()
    assert at_start.select(pl.col("state").str.slice(pl.col("e_link_index"), 1))["state"].is_in(["G", "g"]).all()
    assert at_start["e_front_m"].is_between(-10 - 1e-6, 10 + 1e-6).all()
    assert (at_start["a_from_edge"] != at_start["e_from_edge"]).all() and (at_start["a_front_m"] >= -10 - 1e-6).all()
    # the actor leaves the junction before the ego does, and each ego waited for the actor it is labelled with
    # only once
    out = rows.filter(pl.col("front_m") >= pl.col("total_m")).group_by("vehicle_id").agg(out_s=pl.col("t_s").min())
    order = labels.join(out, left_on="ego_id", right_on="vehicle_id").join(
        out, left_on="actor_id", right_on="vehicle_id", suffix="_actor")
    assert order.height == labels.height and (order["out_s_actor"] < order["out_s"]).all()
    assert labels.select("ego_id", "actor_id").is_unique().all()


@needs_fixtures
def test_disagreements_name_a_reason_and_the_command_prints_them(capsys):
    diff = compare(JUNCTION)
    assert diff["reason"].is_not_null().all()
    # every pair is labelled by one labeller only, or by both with intervals that do not pair up
    only_one = diff["phase_start_s"].is_null() | diff["conflict_start_s"].is_null()
    assert (only_one | (diff["iou"] < 0.5)).all()
    assert main([str(JUNCTION)]) == 0
    printed = capsys.readouterr().out
    assert "| junction_s1 |" in printed and "| reason | pairs |" in printed
