"""Scoring matches against labels: hand-derived numbers on synthetic intervals (10 Hz, one drive)."""

from __future__ import annotations

import polars as pl
import pytest

from logiq_sql.cli import build_parser
from logiq_sql.core.errors import InputError
from logiq_sql.evaluation.evaluate import evaluate
from logiq_sql.storage import db, tables

DT = 0.1


def make_file(tmp_path, matches, egos=("E1",), other_actors=("A", "B"), frames=100, drive="d1"):
    """A DuckDB file as `match` leaves it: one drive, ``frames`` samples of every ego and actor, the given
    matches ``(scenario, ego, actor, start_s, end_s)`` and ego_lanes rows for ``egos``."""
    path = tmp_path / "eval.duckdb"
    path.unlink(missing_ok=True)
    con = db.connect(path)
    tables.insert(con, "drive_inputs", pl.DataFrame([{
        "drive_id": drive, "source_format": "parquet", "source_path": "x", "dt_s": DT, "rows_read": 0,
        "rows_rejected": 0, "status": "ingested"}]))
    actors = sorted({*egos, "E2", *other_actors})
    tables.insert(con, "tracks", pl.DataFrame([{
        "drive_id": drive, "actor_id": a, "kind": "vehicle", "is_ego": False, "frame": f, "t_s": round(f * DT, 6),
        "x_m": 0.0, "y_m": 0.0} for a in actors for f in range(frames)]))
    rows = [{"match_id": f"m{i}", "scenario": s, "scenario_version": 1, "params_hash": "h", "drive_id": drive,
             "ego_id": e, "actor_id": a, "start_frame": round(t0 / DT), "end_frame": round(t1 / DT), "start_s": t0,
             "end_s": t1, "duration_s": t1 - t0} for i, (s, e, a, t0, t1) in enumerate(matches)]
    tables.insert(con, "matches", pl.DataFrame(rows, schema=tables.MATCHES.polars_schema))
    con.execute("create table ego_lanes (drive_id varchar, ego_id varchar, frame bigint)")
    con.execute("insert into ego_lanes select drive_id, actor_id, frame from tracks "
                "where actor_id in (select unnest($e))", {"e": list(egos)})
    con.close()
    return path


def write_labels(tmp_path, labels, drive="d1", name="labels.parquet"):
    path = tmp_path / name
    pl.DataFrame([{"drive_id": drive, "scenario": s, "ego_id": e, "actor_id": a, "start_s": t0, "end_s": t1,
                   "source": "test"} for s, e, a, t0, t1 in labels]).write_parquet(path)
    return path


def score(result, scenario):
    return result.scores.filter(pl.col("scenario") == scenario).row(0, named=True)


def test_iou_edge_cases(tmp_path):
    # frames count: [1.0, 1.9] is frames 10..19 (10 frames)
    labels = [
        ("third", "E1", "A", 1.0, 1.9),   # vs [1.5, 2.4]: 5 shared of 15 frames -> IoU 1/3
        ("half", "E1", "A", 1.0, 1.9),    # vs [1.0, 2.9]: 10 of 20 -> exactly 0.5, a hit at >= 0.5
        ("point", "E1", "A", 3.0, 3.0),   # single frames at the same time -> IoU 1
        ("touch", "E1", "A", 0.0, 0.9),   # vs [1.0, 1.9]: adjacent, no shared frame -> IoU 0
    ]
    preds = [("third", "E1", "A", 1.5, 2.4), ("half", "E1", "A", 1.0, 2.9), ("point", "E1", "A", 3.0, 3.0),
             ("touch", "E1", "A", 1.0, 1.9)]
    result = evaluate(make_file(tmp_path, preds), write_labels(tmp_path, labels))
    assert [(r["tp"], r["fp"], r["fn"]) for r in result.scores.sort("scenario").iter_rows(named=True)] == [
        (1, 0, 0), (1, 0, 0), (0, 1, 1), (0, 1, 1)]  # half, point, third, touch
    best = result.events.filter(pl.col("role") == "label").sort("scenario")["best_iou"].to_list()
    assert best == pytest.approx([0.5, 1.0, 1 / 3, 0.0])
    # at a threshold of exactly 1/3 the third pair is a hit
    lower = evaluate(make_file(tmp_path, preds), write_labels(tmp_path, labels), iou_threshold=1 / 3)
    assert score(lower, "third")["tp"] == 1


def test_one_to_one_two_predictions_on_one_label(tmp_path):
    labels = [("s", "E1", "A", 0.0, 1.9)]
    preds = [("s", "E1", "A", 0.0, 1.4), ("s", "E1", "A", 0.0, 1.9)]  # IoU 0.75 and 1.0
    result = evaluate(make_file(tmp_path, preds), write_labels(tmp_path, labels))
    row = score(result, "s")
    assert (row["labels"], row["predictions"], row["tp"], row["fp"], row["fn"]) == (1, 2, 1, 1, 0)
    assert (row["precision"], row["recall"], row["f1"]) == pytest.approx((0.5, 1.0, 2 / 3))
    tp = result.events.filter((pl.col("role") == "prediction") & (pl.col("outcome") == "tp"))
    assert tp["end_s"].to_list() == [1.9] and tp["iou"].to_list() == [1.0]  # greedy takes the better one
    fp = result.events.filter(pl.col("outcome") == "fp")
    assert fp["iou"].to_list() == [None] and fp["best_iou"].to_list() == [0.75]


def test_greedy_pairs_crossing_candidates(tmp_path):
    # L1 [0, 1.9], L2 [0.5, 2.4]; P1 [0, 1.9] (IoU 1 with L1, 0.6 with L2), P2 [0.5, 2.9] (IoU 0.5 with L1,
    # 0.8 with L2): greedy takes L1-P1 (1.0) then L2-P2 (0.8)
    labels = [("s", "E1", "A", 0.0, 1.9), ("s", "E1", "A", 0.5, 2.4)]
    preds = [("s", "E1", "A", 0.0, 1.9), ("s", "E1", "A", 0.5, 2.9)]
    result = evaluate(make_file(tmp_path, preds), write_labels(tmp_path, labels))
    lab = result.events.filter(pl.col("role") == "label").sort("start_s")
    assert lab["matched_end_s"].to_list() == [1.9, 2.9]
    assert lab["iou"].to_list() == pytest.approx([1.0, 20 / 25])


def test_actor_must_agree_for_events_not_for_timestamps(tmp_path):
    result = evaluate(make_file(tmp_path, [("s", "E1", "B", 1.0, 2.9)]),
                      write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.9)]))
    row = score(result, "s")
    assert (row["tp"], row["fp"], row["fn"]) == (0, 1, 1)
    assert (row["tpr"], row["tnr"], row["ba_timestamp"]) == (1.0, 1.0, 1.0)


def test_balanced_accuracy_counts_ego_frames(tmp_path):
    # 100 ego frames; truth frames 10..29, predicted 20..39: TP 10, FN 10, FP 10, TN 70
    result = evaluate(make_file(tmp_path, [("s", "E1", "A", 2.0, 3.9)]),
                      write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.9)]))
    row = score(result, "s")
    assert row["frames"] == 100 and (row["egos"], row["drives"]) == (1, 1)
    assert (row["tpr"], row["tnr"]) == pytest.approx((0.5, 70 / 80))
    assert row["ba_timestamp"] == pytest.approx((0.5 + 70 / 80) / 2)


def test_overlapping_intervals_count_each_frame_once(tmp_path):
    # two actors' labels overlap on frames 15..19: positives are frames 10..24, still 15 frames
    result = evaluate(make_file(tmp_path, [("s", "E1", "A", 1.0, 2.4)]),
                      write_labels(tmp_path, [("s", "E1", "A", 1.0, 1.9), ("s", "E1", "B", 1.5, 2.4)]))
    row = score(result, "s")
    assert (row["tpr"], row["tnr"]) == (1.0, 1.0)


def test_empty_denominators_give_rate_one(tmp_path):
    # every ego frame is labelled and predicted: no negatives, so TNR = 1.0 by the rule
    full = evaluate(make_file(tmp_path, [("s", "E1", "A", 0.0, 9.9)]),
                    write_labels(tmp_path, [("s", "E1", "A", 0.0, 9.9)]))
    assert (score(full, "s")["tpr"], score(full, "s")["tnr"], score(full, "s")["ba_timestamp"]) == (1.0, 1.0, 1.0)
    # predictions of a scenario without labels: no positives, TPR = 1.0; 20 of 100 frames are false positives
    unlabelled = evaluate(make_file(tmp_path, [("p", "E1", "A", 0.0, 1.9)]),
                          write_labels(tmp_path, [("s", "E1", "A", 5.0, 5.9)]))
    row = score(unlabelled, "p")
    assert (row["labels"], row["fp"], row["precision"], row["recall"], row["f1"]) == (0, 1, 0.0, None, 0.0)
    assert (row["tpr"], row["tnr"]) == pytest.approx((1.0, 0.8))
    assert any("p: no labels" in n for n in unlabelled.notes)


def test_scenario_unknown_to_the_file_is_all_false_negatives(tmp_path):
    result = evaluate(make_file(tmp_path, []), write_labels(tmp_path, [("sut_cut_out", "E1", "A", 1.0, 2.0)]))
    row = score(result, "sut_cut_out")
    assert (row["labels"], row["predictions"], row["tp"], row["fn"]) == (1, 0, 0, 1)
    assert (row["precision"], row["recall"], row["f1"]) == (None, 0.0, 0.0)
    assert (row["tpr"], row["tnr"]) == (0.0, 1.0)
    assert any("every label is a FN" in n for n in result.notes)


def test_only_egos_the_matcher_used_and_drives_in_both(tmp_path):
    labels = write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.0), ("s", "E2", "A", 1.0, 2.0)])
    pl.concat([pl.read_parquet(labels), pl.read_parquet(write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.0)],
                                                                      drive="elsewhere", name="x.parquet"))
               ]).write_parquet(labels)
    result = evaluate(make_file(tmp_path, [("s", "E1", "A", 1.0, 2.0)], egos=("E1",)), labels)
    row = score(result, "s")
    assert (row["labels"], row["tp"], row["fn"], row["egos"], row["frames"]) == (1, 1, 0, 1, 100)
    assert any("1 label(s) of 1 ego(s) the matcher did not use" in n for n in result.notes)
    assert any("not in the file (e.g. elsewhere)" in n for n in result.notes)
    assert "note: " in result.summary()


def test_missing_label_column_names_file_column_and_fix(tmp_path):
    path = tmp_path / "bad.parquet"
    pl.DataFrame({"drive_id": ["d1"], "scenario": ["s"], "actor_id": ["A"], "start_s": [0.0], "end_s": [1.0]}
                 ).write_parquet(path)
    with pytest.raises(InputError, match=r"(?s)bad\.parquet: column 'ego_id' is missing.*label sumo"):
        evaluate(make_file(tmp_path, []), path)
    with pytest.raises(InputError, match="no such labels file"):
        evaluate(make_file(tmp_path, []), tmp_path / "none.parquet")


def test_file_without_a_match_run(tmp_path):
    path = tmp_path / "fresh.duckdb"
    db.connect(path).close()
    with pytest.raises(InputError, match="(?s)no table ego_lanes.*logiq-sql match"):
        evaluate(path, write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.0)]))


def test_cli_writes_parquet(tmp_path, capsys):
    parser = build_parser()
    args = parser.parse_args(["evaluate", "--db", str(make_file(tmp_path, [("s", "E1", "A", 1.0, 2.0)])),
                              "--labels", str(write_labels(tmp_path, [("s", "E1", "A", 1.0, 2.0)])),
                              "--iou", "0.7", "--out", str(tmp_path / "out")])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "IoU >= 0.7" in out and "ba_timestamp" in out
    scores = pl.read_parquet(tmp_path / "out/evaluation.parquet")
    assert scores.select("tp", "fp", "fn", "ba_timestamp").row(0) == (1, 0, 0, 1.0)
    assert pl.read_parquet(tmp_path / "out/evaluation_events.parquet")["outcome"].to_list() == ["tp", "tp"]


def test_pooled_f1_sums_the_events_of_every_seed():
    """campaign --pool: F1 from the summed TP, FP and FN of a regime's seeds, beside its lowest run."""
    from logiq_sql.cli.campaign import pooled_markdown

    runs = pl.DataFrame({"scenario": ["s", "s"], "regime": ["r", "r"], "noise": ["exact", "exact"],
                         "tp": [20, 30], "fp": [0, 1], "fn": [3, 0], "f1": [40 / 43, 60 / 61]})
    row = pooled_markdown(runs).splitlines()[2]
    assert row == f"| s | r | exact | 2 | 50 / 1 / 3 | {100 / 104:.3f} | {40 / 43:.3f} |"
