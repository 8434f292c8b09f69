"""KPIs and coverage samples against the rows they summarise, read from the file's own tracks and kept relations
with Polars: the ego's rows, the actor's rows and the pair's relation rows inside the match interval, each with
frames the other one lacks (queries/kpis/match_rows.sql puts them side by side)."""

from __future__ import annotations

import duckdb
import polars as pl
import pytest

from logiq_sql.core.units import factor
from logiq_sql.matching.match import match
from tests.helpers import Y1, actor, make_db, times

MPH_PER_MPS = factor("mps") / factor("mph")


def test_kpis_summarise_the_ego_s_the_actor_s_and_the_pair_s_rows_of_the_interval(tmp_path):
    t = times(6.0)
    ego_x, follower_x = 100 + 10 * t + 0.4 * t * t, 80 + 11 * t + 0.45 * t * t  # both speeding up, closing in
    ego_seen = (t < 4.0) | (t > 4.25)  # the ego is lost for 0.3 s, its follower is not
    follower_seen = (t < 2.0) | (t > 2.15)  # the follower is lost for 0.2 s elsewhere
    path = make_db(tmp_path, [actor("ego", t[ego_seen], ego_x[ego_seen], Y1, is_ego=True),
                              actor("f", t[follower_seen], follower_x[follower_seen], Y1)])
    result = match(path, scenarios=["follower_vehicle"], keep=True)
    [m] = result.matches.iter_rows(named=True)
    assert (m["start_s"], m["end_s"]) == (0.0, 6.0)  # both losses bridged
    [kpi] = result.kpis.iter_rows(named=True)
    with duckdb.connect(str(path), read_only=True) as con:
        tracks = con.sql("select actor_id, frame, speed_mps, accel_mps2, kind from tracks").pl()
        relations = con.sql("select frame, lon_gap_m, ttc_s, mttc_s from relations "
                            "where ego_id = 'ego' and actor_id = 'f'").pl()
        sampled = con.sql("select item, value_num from coverage_samples").pl()
    inside = pl.col("frame").is_between(m["start_frame"], m["end_frame"])
    ego = tracks.filter(pl.col("actor_id") == "ego", inside)
    follower = tracks.filter(pl.col("actor_id") == "f", inside)
    pair = relations.filter(inside)
    assert (ego.height, follower.height, pair.height) == (58, 59, 56)  # each lacks frames the other has
    expected = {
        "ego_max_speed_mph": ego["speed_mps"].max() * MPH_PER_MPS,
        "ego_min_speed_mph": ego["speed_mps"].min() * MPH_PER_MPS,
        "ego_avg_speed_mph": ego["speed_mps"].mean() * MPH_PER_MPS,
        "ego_max_lon_acceleration_mpsps": ego["accel_mps2"].max(),
        "ego_min_lon_acceleration_mpsps": ego["accel_mps2"].min(),
        "vehicle_max_speed_mph": follower["speed_mps"].max() * MPH_PER_MPS,
        "vehicle_min_speed_mph": follower["speed_mps"].min() * MPH_PER_MPS,
        "vehicle_avg_speed_mph": follower["speed_mps"].mean() * MPH_PER_MPS,
        "vehicle_max_lon_acceleration_mpsps": follower["accel_mps2"].max(),
        "vehicle_min_lon_acceleration_mpsps": follower["accel_mps2"].min(),
        "ego_min_distance_to_vehicle_m": pair["lon_gap_m"].min(),
        "ego_min_ttc_to_vehicle_s": pair["ttc_s"].min(),
        "ego_min_mttc_to_vehicle_s": pair["mttc_s"].min(),
    }
    for column, value in expected.items():
        assert kpi[column] == pytest.approx(value, rel=1e-9, abs=1e-12), column
    assert kpi["vehicle_object_kind"] == "vehicle" and kpi["vehicle_tracking_id"] == "f"
    assert kpi["interval_duration_s"] == pytest.approx(6.0)
    # the samples at the match's start: the ego's and the follower's speed at frame 0
    at_start = dict(sampled.iter_rows())
    first = tracks.filter(pl.col("frame") == m["start_frame"]).sort("actor_id")["speed_mps"].to_list()
    assert at_start["ego_speed_at_start"] == pytest.approx(first[0] * MPH_PER_MPS)
    assert at_start["vehicle_speed_at_start"] == pytest.approx(first[1] * MPH_PER_MPS)
