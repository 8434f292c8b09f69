"""Build small hand-made drives: a straight two-lane road along +x and actors driving on it."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import polars as pl

from logiq_sql.ingestion.ingest import ingest

DATA = Path(__file__).resolve().parent / "data"
# one bundled drive of each kind of map, as ``ingested.steps`` takes them: a motorway with lane changes (NGSIM), a
# junction with turns (SUMO), and the real ego logs of AV2 and nuScenes with their HD maps
EVERY_MAP = (("commonroad", [DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"]),
             ("sumo", [DATA / "sumo/junction_s1"]),
             ("av2", [DATA / "av2"]),
             ("scenarionet", [DATA / "nuscenes_mini_scenarionet"]))


@contextlib.contextmanager
def example_dir(tmp_path_factory, name: str) -> Iterator[Path]:
    """A directory for one Hypothesis example, removed when the example ends: a test's examples share its one
    tmp_path, and their DuckDB files and step caches add up to hundreds of MB."""
    path = tmp_path_factory.mktemp(name)
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


LANE_W = 3.5
ROAD_LEN = 2000.0


def lane(lane_id: str, y0: float, x0: float = 0.0, x1: float = ROAD_LEN, left=None, right=None) -> dict:
    return dict(
        map_id="road", lane_id=lane_id, lane_type="test",
        polygon_wkt=f"POLYGON (({x0} {y0}, {x1} {y0}, {x1} {y0 + LANE_W}, {x0} {y0 + LANE_W}, {x0} {y0}))",
        centerline_wkt=f"LINESTRING ({x0} {y0 + LANE_W / 2}, {x1} {y0 + LANE_W / 2})",
        left_lane_id=left, left_same_direction=None if left is None else True,
        right_lane_id=right, right_same_direction=None if right is None else True,
        speed_limit_mps=None, junction_id=None,
    )


# L1 is the right lane (y in [0, 3.5]), L2 its left neighbour; both run along +x.
TWO_LANES = [lane("L1", 0.0, left="L2"), lane("L2", LANE_W, right="L1")]
Y1, Y2 = LANE_W / 2, LANE_W * 1.5  # lane centres


def actor(actor_id: str, t: np.ndarray, x: np.ndarray, y: np.ndarray | float, kind: str = "vehicle",
          is_ego: bool = False, length: float = 4.5, width: float = 1.8, drive_id: str = "d1") -> pl.DataFrame:
    y = np.broadcast_to(np.asarray(y, dtype=float), t.shape)
    return pl.DataFrame({
        "drive_id": drive_id, "actor_id": actor_id, "kind": kind, "is_ego": is_ego,
        "t_s": t, "x_m": np.asarray(x, dtype=float), "y_m": y, "length_m": length, "width_m": width,
    })


def make_db(tmp: Path, actors: list[pl.DataFrame], lanes: list[dict] | None = None,
            successors: list[dict] | None = None, dt: float = 0.1) -> Path:
    """Write the actors and lanes as canonical Parquet and ingest them; returns the DuckDB path."""
    folder = tmp / "parquet"
    folder.mkdir(parents=True, exist_ok=True)
    tracks = pl.concat(actors, how="diagonal")
    tracks.write_parquet(folder / "tracks.parquet")
    drives = tracks.select("drive_id").unique().with_columns(
        dt_s=pl.lit(dt), map_id=pl.lit("road"), ego_actor_id=pl.lit(None, pl.String))
    drives.write_parquet(folder / "drives.parquet")
    pl.DataFrame(lanes if lanes is not None else TWO_LANES).write_parquet(folder / "lanes.parquet")
    if successors:
        pl.DataFrame(successors, schema={"map_id": pl.String, "lane_id": pl.String, "successor_id": pl.String,
                                         "turn": pl.String}).write_parquet(folder / "lane_successors.parquet")
    path = tmp / "test.duckdb"
    ingest("parquet", [folder], path)
    return path


def times(seconds: float, dt: float = 0.1) -> np.ndarray:
    return np.round(np.arange(round(seconds / dt) + 1) * dt, 6)


def intervals(result_matches: pl.DataFrame, scenario: str) -> list[tuple[str, str, float, float]]:
    m = result_matches.filter(pl.col("scenario") == scenario).sort("ego_id", "actor_id", "start_s")
    return [(r["ego_id"], r["actor_id"], round(r["start_s"], 3), round(r["end_s"], 3)) for r in m.iter_rows(named=True)]
