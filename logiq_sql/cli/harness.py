"""``logiq-sql eval simulate|label|evaluate``: the evaluation harness's commands (logiq_sql.evaluation), apart from
the product's."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from logiq_sql.cli.common import EPILOG, EXIT_OK, add_db, add_set, command, db_of, set_pairs
from logiq_sql.core.errors import LogiqError


def cmd_simulate(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.perceive import Noise
    from logiq_sql.evaluation.simulate import Regime, simulate

    regime = Regime(lane_change_duration_s=args.lane_change_duration, truck_share=args.truck_share,
                    bus_share=args.bus_share, approach_lanes=args.approach_lanes, demand=args.demand,
                    creep=args.creep, motorcycle_share=args.motorcycle_share, skew_deg=args.skew,
                    cycle_s=args.cycle, speed_kmh=args.speed, exit_backup=args.exit_backup)
    noise = Noise(position_m=args.noise_position, heading_deg=args.noise_heading, speed_mps=args.noise_speed,
                  drop_share=args.noise_drop, seed=args.seed if args.noise_seed is None else args.noise_seed)
    if noise != Noise(seed=noise.seed) and not args.perceived:
        raise LogiqError("--noise-*: the noise goes into a perceived copy of the run, never into SUMO's own records. "
                         "Fix: add --perceived DIR (the copy is written to DIR/<run folder name>).")
    print(simulate(args.kind, args.minutes, args.seed, args.out, regime=regime, noise=noise,
                   perceived=args.perceived))
    if args.perceived:
        print(f"perceived copy ({noise}): {Path(args.perceived) / Path(args.out).name}")
    return EXIT_OK


def cmd_label(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.labels import label_runs

    labels = label_runs(args.runs, args.scenario or None, set_pairs(args.set))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    labels.write_parquet(out)
    counts = labels.group_by("drive_id", "scenario").len().sort("drive_id", "scenario")
    for r in counts.iter_rows(named=True):
        print(f"  {r['drive_id']}: {r['scenario']}: {r['len']} label(s)", file=sys.stderr)
    print(f"{out}: {labels.height} label(s) of {labels['drive_id'].n_unique()} run(s)")
    return EXIT_OK


def cmd_evaluate(args: argparse.Namespace) -> int:
    from logiq_sql.evaluation.evaluate import evaluate

    result = evaluate(db_of(args), args.labels, iou_threshold=args.iou, out=args.out)
    print(result.summary())
    if args.out:
        print(f"Parquet written to {Path(args.out).resolve()}")
    return EXIT_OK


def add_eval(sub) -> None:
    """``logiq-sql eval simulate|label|evaluate``: the evaluation harness (logiq_sql.evaluation), apart from the
    product's commands."""
    p = sub.add_parser("eval", help="the evaluation harness: simulate drives with SUMO, label them from SUMO's "
                       "records, score matches (docs/evaluation.md)", epilog=EPILOG,
                       description="The evaluation harness: how well the matcher finds what a simulator knows "
                                   "happened (docs/evaluation.md, docs/sumo.md).")
    add_harness(p.add_subparsers(dest="harness", required=True, metavar="COMMAND"))
    add_harness(sub, hidden=True)  # the old top-level names, still parsed; `_run` says where they went


def add_harness(harness, hidden: bool = False) -> None:
    """The harness's commands on ``harness``; ``hidden``: left out of its command list (the old top-level names)."""
    for add in (add_simulate, add_label, add_evaluate):
        add(harness, hidden)


def add_simulate(harness, hidden: bool) -> None:
    s = command(harness, "simulate", cmd_simulate, "simulate drives with Eclipse SUMO (optional extra [sumo])",
                 "Build a motorway or a signalised junction with SUMO's own tools and run it at 0.1 s steps; writes "
                 "the network, routes, FCD and SUMO's reference outputs into DIR, ready for `ingest sumo DIR` "
                 "(docs/sumo.md). Needs pip install 'logiq-sql[sumo]'.", hidden)
    s.add_argument("kind", choices=["motorway", "junction"],
                   help="motorway: 3.5 km, 3 lanes, on- and off-ramp, dense mixed traffic; junction: signalised "
                        "4-way junction with permissive left turns, cars and bicycles")
    s.add_argument("--minutes", type=float, default=5.0, help="simulated minutes (default 5; the first 60 s "
                                                              "are warm-up)")
    s.add_argument("--seed", type=int, default=1, help="random seed (default 1); the same seed gives the same run")
    s.add_argument("--out", required=True, metavar="DIR", help="folder to write the run into")
    add_regime(s)
    add_noise(s)


def add_regime(s: argparse.ArgumentParser) -> None:
    g = s.add_argument_group("regime (docs/sumo.md, Regimes)")
    g.add_argument("--lane-change-duration", type=float, default=3.0, metavar="S",
                   help="seconds a lane change takes (SUMO --lanechange.duration; default 3; 0 = instantaneous)")
    g.add_argument("--truck-share", type=float, default=0.15, metavar="X",
                   help="share of motor vehicles that are trucks (default 0.15)")
    g.add_argument("--bus-share", type=float, default=0.05, metavar="X",
                   help="share of motor vehicles that are buses or coaches (default 0.05)")
    g.add_argument("--demand", type=float, default=1.0, metavar="X", help="factor on every traffic flow (default 1)")
    g.add_argument("--approach-lanes", type=int, default=3, choices=[2, 3, 4],
                   help="junction: lanes per approach, i.e. its size (default 3)")
    g.add_argument("--no-creep", dest="creep", action="store_false",
                   help="junction: left-turners start from the line like other cars (default: they creep)")
    g.add_argument("--motorcycle-share", type=float, default=0.0, metavar="X",
                   help="junction: share of motor vehicles that are motorcycles (default 0)")
    g.add_argument("--skew", type=float, default=0.0, metavar="DEG",
                   help="junction: north and south arms turned this far off the perpendicular, 0-45 (default 0)")
    g.add_argument("--cycle", type=float, default=90.0, metavar="S",
                   help="junction: the signal cycle in seconds, 30-180 (default 90)")
    g.add_argument("--speed", type=float, default=50.0, metavar="KMH",
                   help="junction: the arms' speed limit in km/h, 20-80 (default 50)")
    g.add_argument("--exit-backup", action="store_true",
                   help="junction: exits narrow to one slow lane 50 m on, so they back up into the junction")


def add_noise(s: argparse.ArgumentParser) -> None:
    g = s.add_argument_group("perception-like noise, written to a perceived copy of the run (docs/evaluation.md)")
    g.add_argument("--perceived", metavar="DIR",
                   help="also write DIR/<run folder name>: the run with noisy tracks, for ingest; label the original")
    g.add_argument("--noise-position", type=float, default=0.0, metavar="M",
                   help="standard deviation of the x and y jitter, metres (default 0)")
    g.add_argument("--noise-heading", type=float, default=0.0, metavar="DEG",
                   help="standard deviation of the heading jitter, degrees (default 0)")
    g.add_argument("--noise-speed", type=float, default=0.0, metavar="MPS",
                   help="standard deviation of the speed noise, m/s (default 0)")
    g.add_argument("--noise-drop", type=float, default=0.0, metavar="X",
                   help="share of detections dropped at random (default 0; 0.02 = 2 %%)")
    g.add_argument("--noise-seed", type=int, metavar="N", help="seed of the noise (default: --seed)")


def add_label(harness, hidden: bool) -> None:
    la = command(harness, "label", cmd_label, "ground-truth labels from a simulator's own records (for evaluate)",
                  "Label scenarios in SUMO run folders from SUMO's own records (FCD leader, lane-change output, "
                  "lanes and lane positions, vType boxes, the network's connections, signal states), independently "
                  "of logiq_sql's SQL; `logiq-sql eval evaluate` scores matches against them. Definitions: "
                  "docs/evaluation.md.", hidden)
    la.add_argument("source", choices=["sumo"], help="sumo: run folders written by logiq-sql eval simulate")
    la.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders, or folders holding them")
    la.add_argument("--out", required=True, metavar="FILE", help="labels Parquet file to write")
    la.add_argument("--scenario", action="append", metavar="NAME",
                    help="scenario to label (repeatable; default every scenario the labeller knows, "
                         "docs/evaluation.md)")
    add_set(la)


def add_evaluate(harness, hidden: bool) -> None:
    ev = command(harness, "evaluate", cmd_evaluate, "score the matches of a DuckDB file against ground-truth labels",
                  "Per scenario: event-level precision, recall and F1 (one-to-one pairs at temporal IoU >= --iou) "
                  "and timestamp balanced accuracy over every frame of the egos the matcher used. Definitions: "
                  "docs/evaluation.md.", hidden)
    add_db(ev, "DuckDB file after logiq-sql match")
    ev.add_argument("--labels", required=True, metavar="FILE",
                    help="labels Parquet (e.g. from logiq-sql eval label sumo)")
    ev.add_argument("--iou", type=float, default=0.5, metavar="X", help="IoU threshold of an event hit (default 0.5)")
    ev.add_argument("--out", metavar="DIR", help="write evaluation.parquet and evaluation_events.parquet into DIR")
