"""logiq_sql: find LogIQ evaluation scenarios in recorded and simulated drives with SQL over DuckDB.

    import logiq_sql as lq

    lq.ingest("commonroad", ["tests/data/commonroad_ngsim"], "drives.duckdb")
    result = lq.match("drives.duckdb", scenarios=["follower_vehicle"],
                      overrides={"max_distance_from_sut_in_time_units": "3s"})
    result.matches          # polars.DataFrame, one row per match
    print(lq.render("cyclist_close_to_moving_sut"))   # the SQL that runs
    lq.match_frames(tracks, lanes=lanes)   # frames in, frames out, nothing written (logiq_sql/matching/frames.py)
    con = lq.connect("drives.duckdb")       # read-only: the state the last completed run published
    con.sql("select scenario, count(*) from matches group by 1").pl()

Every option is keyword-only; errors name the Python argument (``overrides['max_gap']='4'``), not the flag.
"""

from __future__ import annotations

from importlib.metadata import version
from pathlib import Path

import duckdb

from logiq_sql.core.errors import InputError as InputError
from logiq_sql.core.errors import LogiqError as LogiqError
from logiq_sql.core.errors import ScenarioError as ScenarioError
from logiq_sql.core.errors import UnitError as UnitError
from logiq_sql.ingestion.ingest import ingest as ingest
from logiq_sql.matching.frames import FramesResult as FramesResult
from logiq_sql.matching.frames import match_frames as match_frames
from logiq_sql.matching.match import MatchResult as MatchResult
from logiq_sql.matching.match import match as match
from logiq_sql.matching.match import match_dataset as match_dataset
from logiq_sql.matching.match import render as render
from logiq_sql.spec.scenario import list_scenarios as list_scenarios
from logiq_sql.spec.scenario import load_scenario as load_scenario
from logiq_sql.storage import db as _db

__all__ = [
    "FramesResult", "InputError", "LogiqError", "MatchResult", "ScenarioError", "UnitError", "connect", "ingest",
    "list_scenarios", "load_scenario", "match", "match_dataset", "match_frames", "render",
]
__version__ = version("logiq-sql")  # from the installed metadata: pyproject.toml is the one place


def connect(path: str | Path, *, read_only: bool = True) -> duckdb.DuckDBPyConnection:
    """Open a logiq_sql DuckDB file. Read-only by default: the file as the last completed run published it, never
    blocked by a run and never blocking one. ``read_only=False`` opens it read-write in place (creating it with every
    table): only for a file no run and no reader uses, since a run that finds its file changed under its copy does
    not publish (docs/operations.md)."""
    return _db.open_for_read(path) if read_only else _db.connect(path)
