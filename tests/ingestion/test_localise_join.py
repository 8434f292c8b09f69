"""Map localisation as a join (``benchmarks/localise_join.py``, not wired in: it was exact but not faster) gives
the rows of the shapely localisation ingest used (``benchmarks.shapely_lanes.shapely_locate``, the reference): on a bundled
drive of every map kind, and on hand-made polygons (a concave notch, a hole, an invalid bow-tie, a repeated
centre-line vertex) with points on vertices, on edges, in the hole and the notch, at lane ends and 3 m away."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from benchmarks.localise_join import join_locate
from benchmarks.shapely_lanes import shapely_locate
from logiq_sql.ingestion.readers.av2 import read_av2
from logiq_sql.ingestion.readers.commonroad import read_commonroad
from logiq_sql.ingestion.readers.scenarionet import read_scenarionet
from logiq_sql.ingestion.readers.sumo import read_sumo

DATA = Path(__file__).parents[1] / "data"
KEY = ["drive_id", "actor_id", "frame", "lane_id"]


def _differences(tracks: pl.DataFrame, lanes: pl.DataFrame) -> tuple[int, pl.DataFrame]:
    """(rows of the reference, the rows that differ: missing on one side, or off by more than 1e-9)."""
    ref, new = shapely_locate(tracks, lanes), join_locate(tracks, lanes)
    both = ref.join(new, on=KEY, how="full", coalesce=True, suffix="_new")
    turn = pl.col("heading_diff_rad") - pl.col("heading_diff_rad_new")
    return ref.height, both.filter(
        pl.col("dist_m").is_null() | pl.col("dist_m_new").is_null()
        | ((pl.col("dist_m") - pl.col("dist_m_new")).abs() > 1e-9) | (turn.abs() > 1e-9))


def _drive(kind: str):
    if kind == "nuscenes":
        return read_scenarionet(DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0061.pkl")[0]
    if kind == "commonroad_ngsim":
        return read_commonroad(min((DATA / "commonroad_ngsim/scenarios_2018b").glob("USA_US101*")))[0]
    if kind == "av2":
        return next(read_av2(min((DATA / "av2/motion_forecasting").iterdir())))
    return next(read_sumo(DATA / "sumo" / kind))


@pytest.mark.parametrize("kind", ["nuscenes", "commonroad_ngsim", "av2", "junction_s1", "motorway_s1"])
def test_the_join_gives_the_shapely_rows_on_every_map_kind(kind):
    drive = _drive(kind)
    tracks = drive.tracks.with_columns(pl.col("heading_rad").fill_null(0.0))
    if tracks.height > 60_000:  # the SUMO motorway: every 4th frame keeps the test short
        tracks = tracks.filter(pl.col("frame") % 4 == 0)
    rows, differ = _differences(tracks, drive.lanes)
    assert rows > 1000 and differ.is_empty(), differ


def test_the_join_gives_the_shapely_rows_on_hand_made_edge_cases():
    lanes = pl.DataFrame({
        "lane_id": ["notched", "holed", "bowtie", "straight"],
        "polygon_wkt": [
            "POLYGON ((0 0, 10 0, 10 10, 6 10, 6 4, 4 4, 4 10, 0 10, 0 0))",
            "POLYGON ((20 0, 30 0, 30 10, 20 10, 20 0), (23 3, 27 3, 27 7, 23 7, 23 3))",
            "POLYGON ((40 0, 50 10, 50 0, 40 10, 40 0))",  # invalid: its reach falls back to the box
            "POLYGON ((60 0, 80 0, 80 3.5, 60 3.5, 60 0))",
        ],
        "centerline_wkt": ["LINESTRING (2 0, 2 10)", "LINESTRING (21.5 0, 21.5 10)", "LINESTRING (40 5, 50 5)",
                           "LINESTRING (60 1.75, 70 1.75, 70 1.75, 80 1.75)"],
    })
    on_purpose = [(0, 0), (10, 0), (5, 0), (5, 4), (5, 7), (6, 7), (4, 10), (5, 10.5), (25, 5), (23, 5), (23, 3),
                  (26.5, 6.5), (45, 5), (45, 2), (45, 8), (42, 5), (48, 1), (60, 1.75), (80, 1.75), (83, 1.75),
                  (70, 1.75), (70, 0), (70, -3), (70, 6.5), (13, 5), (-3, 0), (82.5, 3.5), (2, 5), (2, 10),
                  (21.5, 10), (33, 10), (-3 / np.sqrt(2), -3 / np.sqrt(2))]
    rng = np.random.default_rng(3)
    xy = np.r_[np.array(on_purpose), np.c_[rng.uniform(-4, 84, 3000), rng.uniform(-4, 14, 3000)]]
    tracks = pl.DataFrame({"drive_id": "d", "actor_id": [f"a{i}" for i in range(len(xy))], "kind": "vehicle",
                           "frame": 0, "x_m": xy[:, 0], "y_m": xy[:, 1],
                           "heading_rad": rng.uniform(-np.pi, np.pi, len(xy))})
    rows, differ = _differences(tracks, lanes)
    assert rows > 1000 and differ.is_empty(), differ
