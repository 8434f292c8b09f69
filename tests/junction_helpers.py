"""A hand-made signalised junction: a north-south road crossing a west arm, with a left turn from the south.

Junction J is the square x, y in [-10, 10]. Lanes are 3.5 m wide; every path is known in closed form, so the
phases of a scenario can be worked out by hand from the kinematics.

    S_in   northbound approach, x in [0, 3.5], y < -10          N_in   southbound approach, x in [-3.5, 0], y > 10
    J_SN   S_in -> N_out (straight)                             J_NS   N_in -> S_out (straight)
    J_SW   S_in -> W_out (left): quarter circle about (-10, -10), radius 11.75, from (1.75, -10) to (-10, 1.75)
    W_in   eastbound approach in the outer lane, y = -5.25, x < -10; J_WE its straight path, to E_out (no light)
    N_out, S_out, W_out, E_out  exits
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import shapely

from logiq_sql.core.sql import materialise
from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.runner import prepare_relations
from logiq_sql.spec.plan import parse_ego, phase_steps, resolve_scenarios, run_values

LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"

W = 3.5
R_LEFT = 11.75  # radius of the left turn's centre line, about (-10, -10)


def _lane(lane_id: str, line: shapely.LineString, junction: str | None = None) -> dict:
    return dict(map_id="junction", lane_id=lane_id, lane_type="test",
                polygon_wkt=shapely.buffer(line, W / 2, cap_style="flat").wkt, centerline_wkt=line.wkt,
                left_lane_id=None, left_same_direction=None, right_lane_id=None, right_same_direction=None,
                speed_limit_mps=None, junction_id=junction)


def left_arc(n: int = 50) -> np.ndarray:
    a = np.linspace(0, np.pi / 2, n)
    return np.column_stack([-10 + R_LEFT * np.cos(a), -10 + R_LEFT * np.sin(a)])


LANES = [
    _lane("S_in", shapely.LineString([(1.75, -200), (1.75, -10)])),
    _lane("N_out", shapely.LineString([(1.75, 10), (1.75, 200)])),
    _lane("N_in", shapely.LineString([(-1.75, 200), (-1.75, 10)])),
    _lane("S_out", shapely.LineString([(-1.75, -10), (-1.75, -200)])),
    _lane("W_out", shapely.LineString([(-10, 1.75), (-200, 1.75)])),
    _lane("J_SN", shapely.LineString([(1.75, -10), (1.75, 10)]), "J"),
    _lane("J_NS", shapely.LineString([(-1.75, 10), (-1.75, -10)]), "J"),
    _lane("J_SW", shapely.LineString(left_arc()), "J"),
    _lane("W_in", shapely.LineString([(-200, -5.25), (-10, -5.25)])),
    _lane("J_WE", shapely.LineString([(-10, -5.25), (10, -5.25)]), "J"),
    _lane("E_out", shapely.LineString([(10, -5.25), (200, -5.25)])),
]
SUCCESSORS = [
    ("S_in", "J_SN", "straight"), ("S_in", "J_SW", "left"), ("J_SN", "N_out", None), ("J_SW", "W_out", None),
    ("N_in", "J_NS", "straight"), ("J_NS", "S_out", None), ("W_in", "J_WE", "straight"), ("J_WE", "E_out", None),
]


def path_positions(s: np.ndarray, route: str) -> tuple[np.ndarray, np.ndarray]:
    """x, y at path position s (m) along a route; s = 0 where the route enters the junction."""
    if route == "S_left":
        arc = np.clip(s, 0, R_LEFT * np.pi / 2) / R_LEFT
        x = np.where(s < 0, 1.75, -10 + R_LEFT * np.cos(arc))
        y = np.where(s < 0, -10 + s, -10 + R_LEFT * np.sin(arc))
        beyond = s > R_LEFT * np.pi / 2
        x = np.where(beyond, -10 - (s - R_LEFT * np.pi / 2), x)
        return x, np.where(beyond, 1.75, y)
    if route == "N_straight":
        return np.full_like(s, -1.75), 10 - s
    if route == "W_straight":
        return -10 + s, np.full_like(s, -5.25)
    raise ValueError(route)


def drive(actor_id: str, t: np.ndarray, s: np.ndarray, route: str, is_ego: bool = False) -> pl.DataFrame:
    x, y = path_positions(s, route)
    return pl.DataFrame({"drive_id": "j1", "actor_id": actor_id, "kind": "vehicle", "is_ego": is_ego,
                         "t_s": t, "x_m": x, "y_m": y, "length_m": 4.5, "width_m": 1.8})


def make_junction_db(tmp: Path, actors: list[pl.DataFrame], light: str | list[str] | None = "green") -> Path:
    """Ingest the actors on the junction map; ``light`` is the state, at every frame (or frame by frame from 0:
    a list, its last state held), of the light that governs the left turn from S_in and of the one for N_in's
    straight movement (None: the map has no lights)."""
    folder = tmp / "parquet"
    folder.mkdir(parents=True, exist_ok=True)
    tracks = pl.concat(actors)
    tracks.write_parquet(folder / "tracks.parquet")
    pl.DataFrame({"drive_id": ["j1"], "dt_s": [0.1], "map_id": ["junction"], "ego_actor_id": ["ego"]}).write_parquet(
        folder / "drives.parquet")
    pl.DataFrame(LANES).write_parquet(folder / "lanes.parquet")
    pl.DataFrame(SUCCESSORS, schema=["lane_id", "successor_id", "turn"], orient="row").with_columns(
        map_id=pl.lit("junction")).write_parquet(folder / "lane_successors.parquet")
    junction = shapely.box(-10, -10, 10, 10).wkt
    pl.DataFrame({"map_id": ["junction"], "junction_id": ["J"], "polygon_wkt": [junction]}).write_parquet(
        folder / "junctions.parquet")
    if light is not None:
        pl.DataFrame({"map_id": "junction", "light_id": ["L_left", "L_through"], "lane_id": ["S_in", "N_in"],
                      "direction": ["left", "straight,right"], "x_m": [1.75, -1.75], "y_m": [-10.0, 10.0]}
                     ).write_parquet(folder / "traffic_lights.parquet")
        frames = np.arange(int(round(tracks["t_s"].max() * 10)) + 1)
        states = light if isinstance(light, str) else np.array(light)[np.minimum(frames, len(light) - 1)]
        pl.DataFrame({"drive_id": "j1", "light_id": np.repeat(["L_left", "L_through"], len(frames)),
                      "frame": np.tile(frames, 2), "state": np.tile(states, 2) if len(np.shape(states)) else states}
                     ).write_parquet(
            folder / "traffic_light_states.parquet")
    path = tmp / "junction.duckdb"
    ingest("parquet", [folder], path)
    return path


def left_turn_frames(db: Path, ego: str = "auto", drives: list[str] | None = None,
                     tables: tuple[str, ...] = ("phase_frames",),
                     overrides: dict[str, str] | None = None) -> dict[str, pl.DataFrame]:
    """The left turn's per-frame conditions (and any other step table named in ``tables``), computed read-only
    from an ingested file the way match() computes them (with match()'s ``overrides``). ``phase_frames`` is the
    frames step with each phase query's ``holds`` as phase_1 .. phase_4."""
    import duckdb

    s = resolve_scenarios([LEFT_TURN], overrides or {})[0]
    keys = "drive_id, ego_id, ego_passage, actor_id, actor_passage, frame"
    with duckdb.connect(str(db), read_only=True) as con:
        run = con.sql("select drive_id from drive_inputs").pl()
        con.register("run_drives", run if drives is None else run.filter(pl.col("drive_id").is_in(drives)))
        values = run_values(s, parse_ego(ego), 200.0)
        prepare_relations(con, [s], values)
        for table, rel in phase_steps(s)[:1 + len(s.phases)]:  # the frames step and the phase queries
            materialise(con, table, rel, values)
        con.execute("create temp table phase_frames as select f.*, "
                    + ", ".join(f"p{i}.holds as phase_{i}" for i in range(1, 5))
                    + " from scenario_frames as f "
                    + " ".join(f"join phase_{i} as p{i} using ({keys})" for i in range(1, 5)))
        return {t: con.sql(f"select * from {t}").pl() for t in tables}
