"""What the pipeline's unavoidable parts cost on their own, as ratios to the floor measured in the same run.

    python -m benchmarks.components --tier M      # after `make bench TIER=M` wrote benchmarks/work/M/parquet

Each part is the least a pipeline of this kind must do, written as one plain DuckDB statement over the tier's
tracks.parquet, with nothing of logiq_sql around it:

    floor          the benchmark floor: scan + group-by over the track columns (benchmarks/tiers.py)
    window         one per-actor window (the previous sample), the least that speeds, headings, lane runs and
                   phase islands need; summed so that nothing is written
    write          the tracks written once into a DuckDB file (what ingest must do so that matching can rerun)
    pair join      every 10th actor paired with every actor of its frame within 200 m (the relation range),
                   counted only: the least work behind any ego-actor relation

The sum of these parts, against the 20x target, says how far any SQL design of the pipeline could get.
Written: benchmarks/results/<TIER>_components.json and .md.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import duckdb

from benchmarks.tiers import FLOOR_SQL, RESULTS, WORK

PARTS = {
    "floor": FLOOR_SQL,
    "window": """
        select sum(step_m) from (
            select x_m - lag(x_m) over (partition by drive_id, actor_id order by frame) as step_m
            from read_parquet($path)
        )""",
    "write": "create table tracks as select * from read_parquet($path)",
    "pair join": """
        with t as (select drive_id, actor_id, frame, x_m, y_m from read_parquet($path)),
        every_tenth as (
            select drive_id, actor_id from (
                select drive_id, actor_id, row_number() over (partition by drive_id order by actor_id) as n
                from (select distinct drive_id, actor_id from t))
            where n % 10 = 1
        ),
        egos as (select t.* from t inner join every_tenth using (drive_id, actor_id))
        select count(*) from egos as e
        inner join t as a
            on e.drive_id = a.drive_id and e.frame = a.frame and e.actor_id <> a.actor_id
            and (a.x_m - e.x_m) * (a.x_m - e.x_m) + (a.y_m - e.y_m) * (a.y_m - e.y_m) <= 40000
        """,
}


def measure(path: Path) -> dict[str, float]:
    seconds: dict[str, float] = {}
    for name, sql in PARTS.items():
        with tempfile.TemporaryDirectory() as tmp, duckdb.connect(str(Path(tmp) / "part.duckdb")) as con:
            start = time.perf_counter()
            con.execute(sql, {"path": str(path)}).fetchall()
            seconds[name] = time.perf_counter() - start
    return seconds


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tier", default="M")
    args = parser.parse_args(argv)
    path = WORK / args.tier / "parquet" / "tracks.parquet"
    if not path.exists():
        raise SystemExit(f"{path} not found: run `make bench TIER={args.tier}` first.")
    first = measure(path)
    second = measure(path)
    seconds = {k: min(first[k], second[k]) for k in first}  # the faster of two rounds, as for the floor
    floor = seconds["floor"]
    parts = {k: {"seconds": v, "ratio_to_floor": v / floor} for k, v in seconds.items()}
    report = {"tier": args.tier, "parts": parts,
              "sum_ratio_to_floor": sum(p["ratio_to_floor"] for k, p in parts.items() if k != "floor"),
              "measured_at": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    lines = [f"# Tier {args.tier}: the pipeline's unavoidable parts alone", "",
             "| part | wall s | x floor |", "|---|---:|---:|"]
    lines += [f"| {k} | {p['seconds']:.2f} | {p['ratio_to_floor']:.1f} |" for k, p in parts.items()]
    lines += ["", f"Sum of the parts other than the floor: **{report['sum_ratio_to_floor']:.1f}x the floor** "
              f"(measured {report['measured_at']})."]
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.tier}_components.json").write_text(json.dumps(report, indent=2))
    (RESULTS / f"{args.tier}_components.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return report


if __name__ == "__main__":
    main()
