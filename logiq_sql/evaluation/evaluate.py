"""Score the matches stored in a logiq_sql DuckDB file against ground-truth labels (e.g. ``label sumo``).

Per scenario, on the drives present in both and the egos the matcher used (``ego_lanes``):

- events: predicted and labelled intervals of the same (drive, scenario, ego, actor) are paired one-to-one,
  greedily by temporal IoU (highest first) among pairs with IoU >= the threshold; TP, FP, FN, precision,
  recall, F1.
- timestamps: every frame of every evaluated ego is positive when any interval of the scenario (any actor)
  covers it; balanced accuracy (TPR + TNR) / 2 as in the Argoverse 2 scenario-mining evaluation, a rate being
  1.0 when its denominator is 0.

docs/evaluation.md has the definitions and the reasons.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core.errors import InputError, did_you_mean
from logiq_sql.core.sql import registered
from logiq_sql.storage import db

KEY = ["drive_id", "scenario", "ego_id", "actor_id"]
LABEL_COLUMNS = {
    "drive_id": (pl.String, "the drive, as in drive_inputs.drive_id"),
    "scenario": (pl.String, "the scenario name, e.g. follower_vehicle"),
    "ego_id": (pl.String, "actor_id of the ego (SUT)"),
    "actor_id": (pl.String, "actor_id of the scenario's other actor"),
    "start_s": (pl.Float64, "t_s of the first frame of the labelled interval"),
    "end_s": (pl.Float64, "t_s of the last frame (inclusive)"),
}
SCORE_SCHEMA = {
    "scenario": pl.String, "labels": pl.Int64, "predictions": pl.Int64, "tp": pl.Int64, "fp": pl.Int64,
    "fn": pl.Int64, "precision": pl.Float64, "recall": pl.Float64, "f1": pl.Float64, "iou_threshold": pl.Float64,
    "ba_timestamp": pl.Float64, "tpr": pl.Float64, "tnr": pl.Float64, "egos": pl.Int64, "drives": pl.Int64,
    "frames": pl.Int64,
}
EVENT_SCHEMA = {
    "scenario": pl.String, "drive_id": pl.String, "ego_id": pl.String, "actor_id": pl.String, "role": pl.String,
    "start_s": pl.Float64, "end_s": pl.Float64, "ref": pl.String, "outcome": pl.String, "iou": pl.Float64,
    "matched_start_s": pl.Float64, "matched_end_s": pl.Float64, "best_iou": pl.Float64,
}
IOU_EPS = 1e-9  # an IoU of exactly the threshold counts as a hit despite float rounding


@dataclass
class Evaluation:
    """Scores per scenario, every label and prediction with its outcome, and what was left out and why."""

    scores: pl.DataFrame
    events: pl.DataFrame
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        shown = self.scores.select(
            "scenario", "labels", "predictions", "tp", "fp", "fn", "precision", "recall", "f1",
            "ba_timestamp", "tpr", "tnr", "egos", "drives")
        with pl.Config(tbl_rows=-1, tbl_cols=-1, tbl_width_chars=200, tbl_hide_dataframe_shape=True,
                       tbl_hide_column_data_types=True, float_precision=3, fmt_str_lengths=40):
            table = str(shown)
        threshold = self.scores["iou_threshold"][0] if self.scores.height else None
        head = f"events paired one-to-one at temporal IoU >= {threshold:g}" if threshold is not None else ""
        return "\n".join([head, table, *(f"note: {n}" for n in self.notes)])

    def write(self, out: str | Path) -> None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        self.scores.write_parquet(out / "evaluation.parquet")
        self.events.write_parquet(out / "evaluation_events.parquet")


def read_labels(path: str | Path) -> pl.DataFrame:
    """The labels Parquet file with its required columns typed; every problem names the file and the fix."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such labels file.\n\nHint: write one with "
                         f"`logiq-sql label sumo RUN_DIR --out {path}`.")
    try:
        frame = pl.read_parquet(path)
    except (pl.exceptions.PolarsError, OSError) as exc:
        raise InputError(f"{path}: not a readable Parquet file ({exc}).") from None
    for name, (dtype, meaning) in LABEL_COLUMNS.items():
        if name not in frame.columns:
            raise InputError(
                f"{path}: column '{name}' is missing ({meaning}).{did_you_mean(name, frame.columns)}\n\n"
                f"Hint: a labels file needs the columns {', '.join(LABEL_COLUMNS)}; "
                "`logiq-sql label sumo` writes them.")
        try:
            frame = frame.with_columns(pl.col(name).cast(dtype))
        except pl.exceptions.PolarsError:
            raise InputError(f"{path}: column '{name}' must be {dtype} ({meaning}), "
                             f"not {frame.schema[name]}.") from None
    if "source" not in frame.columns:
        frame = frame.with_columns(source=pl.lit(None, pl.String))
    bad = frame.filter(pl.any_horizontal(pl.col(*LABEL_COLUMNS).is_null()) | (pl.col("end_s") < pl.col("start_s")))
    if bad.height:
        row = bad.row(0, named=True)
        raise InputError(f"{path}: {bad.height} label(s) with an empty key or end_s < start_s, e.g. {row}.\n\n"
                         "Hint: every label needs all of " + ", ".join(LABEL_COLUMNS) + " and start_s <= end_s.")
    return frame.select(*LABEL_COLUMNS, pl.col("source").cast(pl.String))


def _open(db_path: str | Path) -> duckdb.DuckDBPyConnection:
    path = Path(db_path)
    if not path.is_file():
        raise InputError(f"{path}: no such DuckDB file.\n\nHint: `logiq-sql ingest` and `logiq-sql match` write one.")
    con = db.connect(path, read_only=True)
    have = {r[0] for r in con.execute("select table_name from duckdb_tables()").fetchall()}
    missing = [t for t in ("drive_inputs", "tracks", "matches", "ego_lanes") if t not in have]
    if missing:
        con.close()
        raise InputError(f"{path}: no table {missing[0]}: the file has not been matched yet.\n\n"
                         f"Hint: run `logiq-sql match --db {path}` first.")
    return con


def _frames(frame: pl.DataFrame, dt: pl.DataFrame) -> pl.DataFrame:
    """Frame indices of intervals, by the tracks' rule frame = round(t_s / dt_s)."""
    return frame.join(dt, on="drive_id").with_columns(
        start_frame=(pl.col("start_s") / pl.col("dt_s")).round().cast(pl.Int64),
        end_frame=(pl.col("end_s") / pl.col("dt_s")).round().cast(pl.Int64),
    ).drop("dt_s")


def pair_intervals(labels: pl.DataFrame, preds: pl.DataFrame,
                   iou_threshold: float) -> tuple[pl.DataFrame, pl.DataFrame]:
    """One-to-one pairs (label_idx, pred_idx, iou) of the same KEY with IoU >= threshold, greedy by IoU,
    and every overlapping pair's IoU (for best_iou).

    IoU counts frames: |frames in both| / |frames in either|. Greedy (take the highest IoU, drop both, repeat)
    is computed in rounds: a pair whose IoU ranks first among every candidate pair of its label and of its
    prediction is the one greedy takes, so each round accepts all such pairs at once.
    """
    pairs = labels.join(preds, on=KEY, suffix="_p").with_columns(
        inter=(pl.min_horizontal("end_frame", "end_frame_p") - pl.max_horizontal("start_frame", "start_frame_p")
               + 1).clip(lower_bound=0))
    pairs = pairs.with_columns(iou=pl.col("inter") / (
        pl.col("end_frame") - pl.col("start_frame") + pl.col("end_frame_p") - pl.col("start_frame_p") + 2
        - pl.col("inter")))
    candidates = (pairs.filter(pl.col("iou") >= iou_threshold - IOU_EPS)
                  .sort(["iou", "label_idx", "pred_idx"], descending=[True, False, False])
                  .with_row_index("rank")
                  .select("label_idx", "pred_idx", "iou", "rank"))
    taken = []
    while candidates.height:
        best = candidates.filter(
            (pl.col("rank") == pl.col("rank").min().over("label_idx"))
            & (pl.col("rank") == pl.col("rank").min().over("pred_idx")))
        taken.append(best)
        candidates = candidates.filter(~pl.col("label_idx").is_in(best["label_idx"].implode())
                                       & ~pl.col("pred_idx").is_in(best["pred_idx"].implode()))
    best_iou = pairs.filter(pl.col("inter") > 0).select("label_idx", "pred_idx", "iou")
    chosen = pl.concat(taken).drop("rank") if taken else pl.DataFrame(
        schema={"label_idx": pl.UInt32, "pred_idx": pl.UInt32, "iou": pl.Float64})
    return chosen, best_iou


def _events(labels: pl.DataFrame, preds: pl.DataFrame, chosen: pl.DataFrame, best_iou: pl.DataFrame):
    best_l = best_iou.group_by("label_idx").agg(best_iou=pl.col("iou").max())
    best_p = best_iou.group_by("pred_idx").agg(best_iou=pl.col("iou").max())
    other_p = preds.select("pred_idx", matched_start_s="start_s", matched_end_s="end_s")
    other_l = labels.select("label_idx", matched_start_s="start_s", matched_end_s="end_s")
    lab = (labels.join(chosen, on="label_idx", how="left").join(other_p, on="pred_idx", how="left")
           .join(best_l, on="label_idx", how="left")
           .with_columns(role=pl.lit("label"), ref=pl.col("source"),
                         outcome=pl.when(pl.col("pred_idx").is_null()).then(pl.lit("fn")).otherwise(pl.lit("tp"))))
    pre = (preds.join(chosen, on="pred_idx", how="left").join(other_l, on="label_idx", how="left")
           .join(best_p, on="pred_idx", how="left")
           .with_columns(role=pl.lit("prediction"), ref=pl.col("match_id"),
                         outcome=pl.when(pl.col("label_idx").is_null()).then(pl.lit("fp")).otherwise(pl.lit("tp"))))
    cols = [pl.col(c).cast(t) for c, t in EVENT_SCHEMA.items()]
    events = pl.concat([lab.select(cols), pre.select(cols)])
    return events.with_columns(pl.col("best_iou").fill_null(0.0)).sort(
        "scenario", "drive_id", "ego_id", "actor_id", "start_s", "role")


TIMESTAMP_SQL = """
with frames as (
    select t.drive_id, t.actor_id as ego_id, t.frame
    from tracks as t
    inner join _egos as e on t.drive_id = e.drive_id and t.actor_id = e.ego_id
),
truth as (
    select distinct l.scenario, f.drive_id, f.ego_id, f.frame
    from _labels as l
    inner join frames as f
        on f.drive_id = l.drive_id and f.ego_id = l.ego_id
        and f.frame >= l.start_frame and f.frame <= l.end_frame
),
pred as (
    select distinct p.scenario, f.drive_id, f.ego_id, f.frame
    from _preds as p
    inner join frames as f
        on f.drive_id = p.drive_id and f.ego_id = p.ego_id
        and f.frame >= p.start_frame and f.frame <= p.end_frame
),
both_sides as (
    select coalesce(t.scenario, p.scenario) as scenario, t.frame is not null as is_true, p.frame is not null as is_pred
    from truth as t
    full outer join pred as p
        on t.scenario = p.scenario and t.drive_id = p.drive_id and t.ego_id = p.ego_id and t.frame = p.frame
)
select
    s.scenario,
    (select count(*) from frames) as frames,
    count(b.scenario) filter (where b.is_true and b.is_pred) as tp_frames,
    count(b.scenario) filter (where b.is_true and not b.is_pred) as fn_frames,
    count(b.scenario) filter (where b.is_pred and not b.is_true) as fp_frames
from _scenarios as s
left join both_sides as b on s.scenario = b.scenario
group by s.scenario
"""


def _rate(num: pl.Expr, den: pl.Expr) -> pl.Expr:
    """Argoverse 2's _safe_rate: 1.0 when nothing could be counted."""
    return pl.when(den == 0).then(1.0).otherwise(num / den)


def _notes(all_labels: pl.DataFrame, dt: pl.DataFrame, egos: pl.DataFrame, preds: pl.DataFrame,
           other_preds: int) -> list[str]:
    """What the scores leave out: labels of drives or egos not matched, matches without labels."""
    notes: list[str] = []
    missing_drives = all_labels.join(dt, on="drive_id", how="anti")["drive_id"].unique().sort()
    if missing_drives.len():
        notes.append(f"{missing_drives.len()} drive(s) of the labels are not in the file (e.g. "
                     f"{missing_drives[0]}): their labels are ignored.")
    ignored = all_labels.join(dt, on="drive_id").join(egos, on=["drive_id", "ego_id"], how="anti")
    if ignored.height:
        notes.append(f"{ignored.height} label(s) of {ignored.select('drive_id', 'ego_id').n_unique()} ego(s) "
                     "the matcher did not use as SUT (not in ego_lanes; match --ego chooses them) are ignored.")
    if other_preds:
        notes.append(f"{other_preds} match(es) of drives without labels, or of egos not in ego_lanes, are ignored.")
    for name in sorted(set(all_labels["scenario"]) - set(preds["scenario"])):
        notes.append(f"{name}: no matches of this scenario on the evaluated egos: every label is a FN.")
    for name in sorted(set(preds["scenario"]) - set(all_labels["scenario"])):
        notes.append(f"{name}: no labels of this scenario: every match is a FP.")
    return notes


def evaluate(db_path: str | Path, labels_path: str | Path, iou_threshold: float = 0.5,
             out: str | Path | None = None) -> Evaluation:
    """Score the matches in ``db_path`` against the labels in ``labels_path``, per scenario.

    Args:
        db_path: a DuckDB file after ``logiq-sql match``.
        labels_path: Parquet with drive_id, scenario, ego_id, actor_id, start_s, end_s (and optionally source).
        iou_threshold: a prediction and a label of the same ego and actor pair up when their IoU reaches this.
        out: also write ``evaluation.parquet`` and ``evaluation_events.parquet`` into this folder.
    """
    if not 0.0 < iou_threshold <= 1.0:
        raise InputError(f"--iou {iou_threshold}: the IoU threshold must be in (0, 1].")
    all_labels = read_labels(labels_path)
    with _open(db_path) as con:
        with registered(con, "_label_drives", all_labels.select("drive_id").unique()):
            dt = con.sql("select drive_id, dt_s from drive_inputs where status = 'ingested' "
                         "and drive_id in (select drive_id from _label_drives)").pl()
        with registered(con, "_dt", dt):
            egos = con.sql("select distinct drive_id, ego_id from ego_lanes "
                           "where drive_id in (select drive_id from _dt)").pl()
        with registered(con, "_egos", egos):
            preds = con.sql("select m.match_id, m.scenario, m.drive_id, m.ego_id, m.actor_id, m.start_s, m.end_s, "
                            "m.start_frame, m.end_frame from matches as m "
                            "inner join _egos as e on m.drive_id = e.drive_id and m.ego_id = e.ego_id").pl()
            other_preds = con.execute("select count(*) from matches as m anti join _egos as e "
                                      "on m.drive_id = e.drive_id and m.ego_id = e.ego_id").fetchall()[0][0]
            scenarios = sorted(set(all_labels["scenario"]) | set(preds["scenario"]))
            labels = (_frames(all_labels.join(egos, on=["drive_id", "ego_id"]), dt)
                      .sort(*KEY, "start_s", "end_s").with_row_index("label_idx"))  # index order breaks IoU ties
            preds = preds.sort(*KEY, "start_s", "end_s").with_row_index("pred_idx")
            with (registered(con, "_labels", labels), registered(con, "_preds", preds),
                  registered(con, "_scenarios", pl.DataFrame({"scenario": scenarios}, schema={"scenario": pl.String}))):
                stamps = con.sql(TIMESTAMP_SQL).pl()
    notes = _notes(all_labels, dt, egos, preds, other_preds)

    chosen, best_iou = pair_intervals(labels, preds, iou_threshold)
    events = _events(labels, preds, chosen, best_iou)
    counts = events.group_by("scenario").agg(
        labels=(pl.col("role") == "label").sum(), predictions=(pl.col("role") == "prediction").sum(),
        tp=((pl.col("role") == "label") & (pl.col("outcome") == "tp")).sum(),
        fp=(pl.col("outcome") == "fp").sum(), fn=(pl.col("outcome") == "fn").sum())
    tp, fp, fn = pl.col("tp"), pl.col("fp"), pl.col("fn")
    tp_f, fn_f, fp_f = pl.col("tp_frames"), pl.col("fn_frames"), pl.col("fp_frames")
    tn_f = pl.col("frames") - tp_f - fn_f - fp_f
    scores = (
        stamps.join(counts, on="scenario", how="left")
        .with_columns(pl.col("labels", "predictions", "tp", "fp", "fn").fill_null(0))
        .with_columns(
            precision=pl.when(tp + fp > 0).then(tp / (tp + fp)),
            recall=pl.when(tp + fn > 0).then(tp / (tp + fn)),
            f1=pl.when(tp + fp + fn > 0).then(2 * tp / (2 * tp + fp + fn)),
            iou_threshold=pl.lit(iou_threshold),
            tpr=_rate(tp_f, tp_f + fn_f), tnr=_rate(tn_f, tn_f + fp_f),
            egos=pl.lit(egos.height), drives=pl.lit(egos["drive_id"].n_unique()))
        .with_columns(ba_timestamp=(pl.col("tpr") + pl.col("tnr")) / 2)
        .select([pl.col(c).cast(t) for c, t in SCORE_SCHEMA.items()])
        .sort("scenario")
    )
    result = Evaluation(scores=scores, events=events, notes=notes)
    if out is not None:
        result.write(out)
    return result
