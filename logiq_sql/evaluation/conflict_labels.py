"""A second ground truth of the unprotected left turn, from events SUMO records, beside ``labels.py``'s.

Why: ``labels.py`` labels a left turn by the scenario's four phases, frame by frame, with the matcher's way of
chaining them (a run of waiting frames that must reach the actor's junction entry), so a reading the two share
cannot show up as a disagreement. This labeller reads the same records as events instead, and asks what a person
watching the replay would answer: which vehicle did the Ego wait for before it turned?

    python -m logiq_sql.evaluation.conflict_labels RUN_DIR [RUN_DIR ...]   # both labellers and where they differ

Per left-turning Ego E (SUMO connection dir ``l``/``L``, leaving the junction in the run) and vehicle actor A of
``kinds`` on a link from another incoming edge whose path crosses E's (``labels.conflict_zones``: the network's
internal-lane shapes swept by the vType widths):

- *crossed*: A's rear leaves the conflict area before E's front reaches it (FCD lane position, vType length);
- *set-off*: E's turn starts the step after its last standstill (speed <= ``stopping_car_speed_limit``) before
  its front reaches the conflict area;
- *the one it waited for*: A is the last actor to leave E's path of those whose front had reached it by the
  set-off (E sets off as the vehicle it waited for clears its path), or left it at most ``max_gap`` before that
  one (two lanes of oncoming traffic passing together), or it leaves it after the set-off (E rolls while A
  clears) and E does not stand again for another vehicle afterwards: every other actor crossed earlier and E
  kept standing after it;
- *at a green*: E stood with its front within [``min_offset_from_junction_start``,
  ``max_offset_from_junction_start``] of the stop line and at most ``max_offset_from_traffic_light`` before it,
  its link's signal green (``tls_states``: ``G``/``g``), while A was approaching (A's front within
  [``min_offset_from_junction_start``, ``max_offset_from_junction_start``] of its own stop line, or past it and not
  yet at E's path, the conflict area; and A not yet clear), at a step after the last red of
  E's link before A's front reached its stop line (a red ends the occurrence: docs/semantics.md).

Interval: from the first such standing step to E's last step with its front inside the junction.
Nothing here reads logiq_sql's tracks, junction tables or SQL. Why each reading: docs/evaluation.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import polars as pl

from logiq_sql.evaluation.labels import (
    EPS,
    GREEN,
    LABEL_SCHEMA,
    LEFT_TURN_DIRS,
    actor_in_frames,
    actor_out_frames,
    conflict_zones,
    ego_in_frames,
    is_vehicle,
    label_sumo,
    load_run,
    load_signals,
    on_paths,
    scenario_values,
)
from logiq_sql.ingestion.readers.sumo import run_folders

SCENARIO = "unprotected_left_turn_with_yield_and_traffic_light"
LABELLER = "conflict: the vehicle the Ego waited for before it set off (events of fcd, net, tls_states)"
_RED = ("r",)  # SUMO link state red (yellow y/Y and red-yellow u are not red)


def _link_states(states: pl.DataFrame, dt: float) -> pl.DataFrame:
    """One row per (tl, frame) with a state record: the string of link states (last record of a frame)."""
    return (states.with_columns(frame=(pl.col("t_s") / dt).round().cast(pl.Int64)).drop("t_s")
            .unique(["tl", "frame"], keep="last").sort("frame"))


def candidates(rows: pl.DataFrame, links: pl.DataFrame, path_lanes: pl.DataFrame, states: pl.DataFrame,
               p: dict, dt: float) -> pl.DataFrame:
    """Every (E, A) whose paths cross, with each test of the label as a column (for the disagreement report).

    Columns: ego_id, actor_id, crossed, waited_for, at_green, exited, start_s, end_s, link, link_f, actor_out (the
    frame A's rear leaves the conflict), set_off (E's set-off frame).
    """
    schema = {"ego_id": pl.String, "actor_id": pl.String, "crossed": pl.Boolean, "waited_for": pl.Boolean,
              "at_green": pl.Boolean, "exited": pl.Boolean, "start_s": pl.Float64, "end_s": pl.Float64,
              "link": pl.String, "link_f": pl.String, "actor_out": pl.Int64, "set_off": pl.Int64}
    if links.is_empty():
        return pl.DataFrame(schema=schema)
    paths = on_paths(rows, links, path_lanes)
    egos = paths.filter(is_vehicle() & pl.col("dir").is_in(LEFT_TURN_DIRS))
    ego_links = egos.select(ego_id="vehicle_id", link="link", from_edge="from_edge", width_m="width_m").unique(
        "ego_id")
    actors = paths.filter(pl.col("kind").is_in(p["kinds"])).select(
        actor_id="vehicle_id", link_f="link", from_edge_f="from_edge", width_m_f="width_m",
        length_m_f="length_m").unique("actor_id")
    zones = conflict_zones(links, path_lanes, ego_links["width_m"].unique().to_list(),
                           actors["width_m_f"].unique().to_list())
    pairs = (ego_links.join(actors, how="cross")
             .filter((pl.col("ego_id") != pl.col("actor_id")) & (pl.col("from_edge") != pl.col("from_edge_f")))
             .join(zones, on=["link", "link_f", "width_m", "width_m_f"]))
    if pairs.is_empty():
        return pl.DataFrame(schema=schema)
    ego_rows = egos.select(ego_id="vehicle_id", frame="frame", t_s="t_s", front_m="front_m",
                           speed_mps="speed_mps", total_m="total_m", tl="tl", link_index="link_index")
    actor_rows = paths.select(actor_id="vehicle_id", frame="frame", front_f="front_m")
    # E's front reaches the conflict; A's rear leaves it; A's front reaches it; A's front reaches its stop line
    # (first step of each)
    ego_in = ego_in_frames(pairs, egos).rename({"ego_in_frame": "ego_in"})
    actor_out = actor_out_frames(pairs, paths).rename({"actor_out_frame": "actor_out"})
    actor_in = actor_in_frames(pairs, paths).rename({"actor_in_frame": "actor_in"})
    actor_entry = (actors.select("actor_id").join(actor_rows, on="actor_id").filter(pl.col("front_f") >= 0)
                   .group_by("actor_id").agg(actor_entry=pl.col("frame").min()))
    pairs = (pairs.join(ego_in, on=["ego_id", "enter_m"], how="left")
             .join(actor_out, on=["actor_id", "leave_m_f", "length_m_f"], how="left")
             .join(actor_in, on=["actor_id", "enter_m_f"], how="left")
             .join(actor_entry, on="actor_id", how="left")
             .with_columns(crossed=pl.col("actor_out").is_not_null() & pl.col("ego_in").is_not_null()
                           & (pl.col("actor_out") <= pl.col("ego_in"))))
    # E's set-off for each conflict: the step after its last standstill before its front reaches the conflict
    stood = ego_rows.filter(pl.col("speed_mps") <= p["stopping_car_speed_limit"] + EPS)
    set_off = (pairs.select("ego_id", "ego_in").unique().drop_nulls().join(stood, on="ego_id")
               .filter(pl.col("frame") < pl.col("ego_in"))
               .group_by("ego_id", "ego_in").agg(set_off=pl.col("frame").max() + 1))
    pairs = pairs.join(set_off, on=["ego_id", "ego_in"], how="left")
    # the last actor to leave E's path of those whose front had reached it when E set off (over all of E's
    # conflicts): E sets off as the vehicle it waited for clears its path
    # (and E's latest set-off over them: a vehicle that clears E's path after E set off counts only if E does not
    # stand again afterwards for another one, as when E rolls into the junction behind a straggler and waits there)
    last_before = (pairs.filter(pl.col("crossed") & (pl.col("actor_in") <= pl.col("set_off")))
                   .group_by("ego_id").agg(last_out=pl.col("actor_out").max(), last_set_off=pl.col("set_off").max()))
    pairs = pairs.join(last_before, on="ego_id", how="left").with_columns(
        waited_for=pl.col("crossed") & pl.col("set_off").is_not_null()
        & (((pl.col("actor_out") > pl.col("set_off")) & (pl.col("actor_out") >= pl.col("last_set_off").fill_null(pl.col("set_off"))))
           | (pl.col("actor_out") >= pl.col("last_out") - math.floor(p["max_gap"] / dt + EPS))))
    # E's link red before A's front reached its stop line: the occurrence starts after the last such step
    light = _link_states(states, dt)
    ego_state = (ego_rows.sort("frame").join_asof(light, on="frame", by="tl", strategy="backward",
                                                  check_sortedness=False)
                 .with_columns(link_state=pl.col("state").str.slice(pl.col("link_index"), 1)))
    reds = ego_state.filter(pl.col("link_state").is_in(_RED)).select("ego_id", red="frame")
    last_red = (pairs.select("ego_id", "actor_id", "actor_entry").unique().join(reds, on="ego_id")
                .filter(pl.col("red") < pl.col("actor_entry"))
                .group_by("ego_id", "actor_id").agg(last_red=pl.col("red").max()))
    lo, hi = p["min_offset_from_junction_start"] - EPS, p["max_offset_from_junction_start"] + EPS
    standing = ego_state.filter(
        (pl.col("speed_mps") <= p["stopping_car_speed_limit"] + EPS) & pl.col("front_m").is_between(lo, hi)
        & (pl.col("front_m") >= -p["max_offset_from_traffic_light"] - EPS) & (pl.col("front_m") < pl.col("total_m"))
        & pl.col("link_state").is_in(GREEN)).select("ego_id", "frame", "t_s")
    approaching = actor_rows.filter(pl.col("front_f") >= lo).select("actor_id", "frame", "front_f")
    starts = (pairs.select("ego_id", "actor_id", "actor_out", "actor_in").unique()
              .join(last_red, on=["ego_id", "actor_id"], how="left")
              .join(standing, on="ego_id").join(approaching, on=["actor_id", "frame"])
              .filter((pl.col("frame") <= pl.col("actor_out"))
                      & ((pl.col("front_f") <= hi) | (pl.col("frame") < pl.col("actor_in")))
                      & (pl.col("frame") > pl.col("last_red").fill_null(-1)))
              .group_by("ego_id", "actor_id").agg(start_s=pl.col("t_s").min()))
    inside = (ego_rows.group_by("ego_id")
              .agg(end_s=pl.col("t_s").filter((pl.col("front_m") >= -EPS)
                                              & (pl.col("front_m") < pl.col("total_m"))).max(),
                   exited=(pl.col("front_m") >= pl.col("total_m")).any()))
    return (pairs.join(starts, on=["ego_id", "actor_id"], how="left").join(inside, on="ego_id", how="left")
            .with_columns(at_green=pl.col("start_s").is_not_null(), exited=pl.col("exited").fill_null(False))
            # one row per (E, A): an actor with two conflict areas with E (two widths never occur together)
            .sort("ego_id", "actor_id", pl.col("waited_for").not_(), pl.col("at_green").not_())
            .unique(["ego_id", "actor_id"], keep="first")
            .select(*schema).cast(schema))


def label_conflicts(run_dir: str | Path, overrides: dict[str, str] | None = None,
                    with_candidates: bool = False) -> pl.DataFrame:
    """Labels (``labels.LABEL_SCHEMA``) of the left turn in one SUMO run folder by this labeller; with
    ``with_candidates`` every crossing (E, A) with its tests instead (drive_id added)."""
    p = scenario_values([SCENARIO], overrides)[SCENARIO]
    drive_id, dt, rows, _ = load_run(run_dir)
    links, path_lanes, states = load_signals(run_dir)
    found = candidates(rows, links, path_lanes, states, p, dt).with_columns(drive_id=pl.lit(drive_id))
    if with_candidates:
        return found
    return (found.filter(pl.col("crossed") & pl.col("waited_for") & pl.col("at_green") & pl.col("exited")
                         & (pl.col("end_s") - pl.col("start_s") >= p["max_gap"] - EPS))
            .select("drive_id", scenario=pl.lit(SCENARIO), ego_id="ego_id", actor_id="actor_id", start_s="start_s",
                    end_s="end_s", source=pl.format("{}; ego link {} crosses actor link {}", pl.lit(LABELLER),
                                                    "link", "link_f"))
            .cast(LABEL_SCHEMA).sort("ego_id", "actor_id"))


def compare(run_dir: str | Path, overrides: dict[str, str] | None = None) -> pl.DataFrame:
    """Where the two labellers disagree on one run: one row per (ego, actor) labelled by one of them only, or by
    both with intervals of IoU < 0.5, with the reason this labeller gives (its first test that fails)."""
    phases = label_sumo(run_dir, [SCENARIO], overrides).select(
        "drive_id", "ego_id", "actor_id", phase_start_s="start_s", phase_end_s="end_s")
    events = label_conflicts(run_dir, overrides).select(
        "drive_id", "ego_id", "actor_id", conflict_start_s="start_s", conflict_end_s="end_s")
    tests = label_conflicts(run_dir, overrides, with_candidates=True)
    both = phases.join(events, on=["drive_id", "ego_id", "actor_id"], how="full", coalesce=True)
    inter = (pl.min_horizontal("phase_end_s", "conflict_end_s")
             - pl.max_horizontal("phase_start_s", "conflict_start_s")).clip(lower_bound=0)
    union = (pl.max_horizontal("phase_end_s", "conflict_end_s")
             - pl.min_horizontal("phase_start_s", "conflict_start_s"))
    reason = (pl.when(pl.col("conflict_start_s").is_null() & pl.col("crossed").is_null())
              .then(pl.lit("conflict: paths do not cross (no conflict area at these widths)"))
              .when(pl.col("phase_start_s").is_null())
              .then(pl.lit("phases: the waiting run does not reach the actor's entry, or the Ego set off more than "
                            "max_gap after the actor's crossing"))
              .when(pl.col("conflict_start_s").is_not_null()).then(pl.lit("both: intervals differ (IoU < 0.5)"))
              .when(~pl.col("crossed")).then(pl.lit("conflict: the actor did not clear the Ego's path first"))
              .when(~pl.col("waited_for")).then(pl.lit("conflict: not the last to clear before the Ego set off"))
              .when(~pl.col("at_green")).then(pl.lit("conflict: the Ego did not stand at a green (after the last "
                                                     "red) while the actor approached"))
              .otherwise(pl.lit("conflict: shorter than max_gap or the Ego did not leave")))
    return (both.join(tests.select("drive_id", "ego_id", "actor_id", "crossed", "waited_for", "at_green"),
                      on=["drive_id", "ego_id", "actor_id"], how="left")
            .with_columns(iou=pl.when(union > 0).then(inter / union))
            .filter(pl.col("phase_start_s").is_null() | pl.col("conflict_start_s").is_null()
                    | (pl.col("iou").fill_null(0) < 0.5))
            .with_columns(reason=reason)
            .sort("drive_id", "ego_id", "actor_id"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m logiq_sql.evaluation.conflict_labels", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", metavar="RUN_DIR", help="SUMO run folders (or folders of them)")
    args = ap.parse_args(argv)
    diffs, counts = [], []
    for folder in (f for path in args.runs for f in run_folders(path)):
        d = compare(folder)
        diffs.append(d)
        phases = label_sumo(folder, [SCENARIO]).height
        counts.append((folder.name, phases, label_conflicts(folder).height, d.height))
    print("| run | phase labels | conflict labels | disagreements |\n|---|---:|---:|---:|")
    for name, a, b, n in counts:
        print(f"| {name} | {a} | {b} | {n} |")
    every = pl.concat(diffs)
    print("\n| reason | pairs |\n|---|---:|")
    for reason, n in every.group_by("reason").len().sort("len", descending=True).iter_rows():
        print(f"| {reason} | {n} |")
    with pl.Config(tbl_rows=40, tbl_cols=-1, tbl_width_chars=220, fmt_str_lengths=70):
        print(every.select("drive_id", "ego_id", "actor_id", "phase_start_s", "phase_end_s", "conflict_start_s",
                           "conflict_end_s", "reason").head(40))
    return 0


if __name__ == "__main__":
    sys.exit(main())
