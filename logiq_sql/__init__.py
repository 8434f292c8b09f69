"""logiq_sql: find LogIQ evaluation scenarios in recorded and simulated drives with SQL over DuckDB.

    import logiq_sql as lq

    lq.ingest("commonroad", ["tests/data/commonroad_ngsim"], "drives.duckdb")
    result = lq.match("drives.duckdb", scenarios=["follower_vehicle"],
                      overrides={"max_distance_from_sut_in_time_units": "3s"})
    result.matches          # polars.DataFrame, one row per match
    print(lq.render("cyclist_close_to_moving_sut"))   # the SQL that runs
    lq.match_frames(tracks, lanes=lanes)   # frames in, frames out, nothing written (logiq_sql/frames.py)
"""

from __future__ import annotations

from logiq_sql.db import connect as connect
from logiq_sql.errors import InputError as InputError
from logiq_sql.errors import LogiqError as LogiqError
from logiq_sql.errors import ScenarioError as ScenarioError
from logiq_sql.errors import UnitError as UnitError
from logiq_sql.frames import FramesResult as FramesResult
from logiq_sql.frames import match_frames as match_frames
from logiq_sql.ingestion import ingest as ingest
from logiq_sql.match import MatchResult as MatchResult
from logiq_sql.match import match as match
from logiq_sql.match import match_dataset as match_dataset
from logiq_sql.match import render as render
from logiq_sql.scenario import list_scenarios as list_scenarios
from logiq_sql.scenario import load_scenario as load_scenario

__all__ = [
    "FramesResult", "InputError", "LogiqError", "MatchResult", "ScenarioError", "UnitError", "connect", "ingest",
    "list_scenarios", "load_scenario", "match", "match_dataset", "match_frames", "render",
]
__version__ = "0.1.0"
