"""Golden outputs: what the pipeline gives on the bundled drives, kept in tests/golden/ so that an optimisation
that changes a result fails a test (tests/whole/test_golden.py) and the benchmark can say so too.

    python -m tests.golden --write     # regenerate tests/golden/*.parquet from the code as it is now
    python -m tests.golden             # compare the code as it is now with the stored files
    make golden                        # both goldens in one command: these and tier S's (benchmarks/golden/)

Regenerate only with a deliberate change of meaning (a phase, KPI or localisation rule), in a commit of its own
that says so; a speed change must leave them equal.

Drives: every bundled NGSIM scene (CommonRoad), the four nuScenes scenes (ScenarioNet) and the Argoverse 2 logs,
matched with ``--ego auto``; the bundled SUMO junction run, matched with ``--ego every:3``. Kept per setting:

    matches, match_phases, kpis   every column but run_id, sorted
    tracks                        per drive: rows and sums of the derived kinematics (heading, speed, accel)
    track_lanes                   per drive: rows, md5 of the (actor, frame, lane) keys, sums of distances and
                                  heading differences (the localisation)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import duckdb
import polars as pl
from polars.testing import assert_frame_equal

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
GOLDEN = ROOT / "tests" / "golden"
SETTINGS = {
    "real": ([("commonroad", DATA / "commonroad_ngsim"), ("scenarionet", DATA / "nuscenes_mini_scenarionet"),
              ("av2", DATA / "av2")], "auto"),
    "sumo_junction": ([("sumo", DATA / "sumo" / "junction_s1")], "every:3"),
}
# the tables compared, with the query that reads them from a matched file (ordered: the comparison is exact
# for keys and counts, floats within REL_TOL)
TABLES = {
    "matches": "select * exclude (run_id) from matches order by scenario, drive_id, ego_id, actor_id, start_frame",
    "match_phases": "select * from match_phases order by match_id, phase_index",
    "kpis": "select * from kpis order by scenario, match_id",
    "tracks": """select drive_id, count(*) as rows, count(distinct actor_id) as actors, sum(frame) as frames,
                 sum(heading_rad) as heading_sum, sum(speed_mps) as speed_sum, sum(accel_mps2) as accel_sum,
                 sum(abs(accel_mps2)) as accel_abs_sum, count(speed_mps) as speeds, count(accel_mps2) as accels
                 from tracks group by drive_id order by drive_id""",
    # per drive: the md5 of every (actor, frame, lane) key in order, and sums of the values (small files that
    # still change with any lane gained, lost or moved)
    "track_lanes": """select drive_id, count(*) as rows,
                      md5(string_agg(actor_id || '|' || frame || '|' || lane_id, ','
                                     order by actor_id, frame, lane_id)) as keys_md5,
                      sum(dist_m) as dist_sum, sum(abs(heading_diff_rad)) as heading_diff_abs_sum
                      from track_lanes group by drive_id order by drive_id""",
}
REL_TOL = 1e-9  # summation order may move the last bits of a float; a changed rule moves far more


def build(setting: str, folder: Path, ingested=None) -> dict[str, pl.DataFrame]:
    """Ingest and match one setting's drives in ``folder``; the golden tables of the result. ``ingested``: the
    tests' session cache of ingested files (tests/conftest.py), which hands out a copy of the same ingests."""
    from logiq_sql import ingest, match

    sources, ego = SETTINGS[setting]
    db = folder / f"{setting}.duckdb"
    if ingested is not None:
        ingested.steps(db, *((fmt, [path]) for fmt, path in sources))
    else:
        for fmt, path in sources:
            ingest(fmt, [path], db)
    match(db, ego=ego)
    with duckdb.connect(str(db), read_only=True) as con:
        return {name: con.sql(sql).pl() for name, sql in TABLES.items()}


def path_of(setting: str, table: str) -> Path:
    return GOLDEN / f"{setting}_{table}.parquet"


def compare(setting: str, got: dict[str, pl.DataFrame]) -> list[str]:
    """Differences between ``got`` and the stored golden tables of ``setting`` (empty when equal)."""
    problems = []
    for table, frame in got.items():
        want = pl.read_parquet(path_of(setting, table))
        try:
            # kpis gains columns as scenarios are added: compare the golden's columns
            assert_frame_equal(frame.select(want.columns) if table == "kpis" else frame, want,
                               check_exact=False, rel_tol=REL_TOL, abs_tol=1e-12)
        except (AssertionError, pl.exceptions.ColumnNotFoundError) as exc:
            problems.append(f"{setting} {table}: {exc}")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", action="store_true", help="regenerate the golden files from the code as it is")
    args = parser.parse_args(argv)
    problems = []
    with tempfile.TemporaryDirectory() as tmp:
        for setting in SETTINGS:
            got = build(setting, Path(tmp))
            if args.write:
                GOLDEN.mkdir(exist_ok=True)
                for table, frame in got.items():
                    frame.write_parquet(path_of(setting, table), compression="zstd", compression_level=19)
                print(f"{setting}: " + ", ".join(f"{t} {f.height:,} rows" for t, f in got.items()))
            else:
                problems += compare(setting, got)
    for p in problems:
        print(p, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
