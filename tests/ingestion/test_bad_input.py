"""Bad input: every case the "Bad input" section of docs/semantics.md lists, with its exact message or behaviour.

Most cases change one thing in a clean hand-made drive: an ego at 10 m/s in lane L1 for 5 s, and a car 20 m
(centre to centre; 1.55 s headway) behind it, which is one follower_vehicle match over [0 s, 5 s].
"""

from __future__ import annotations

import gzip
import math
import pickle
import shutil
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest

from logiq_sql import ingest, match
from logiq_sql.cli import main
from logiq_sql.core.errors import ScenarioError, UnitError
from logiq_sql.matching.match import resolve_scenarios
from logiq_sql.spec.scenario import load_scenario
from tests.helpers import LANE_W, TWO_LANES, Y1, actor, lane, times

DATA = Path(__file__).parents[1] / "data"
NGSIM = DATA / "commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
NUSCENES = DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0061.pkl"

T = times(5)


def scene(drive_id: str = "d1") -> pl.DataFrame:
    return pl.concat([actor("ego", T, 100 + 10 * T, Y1, is_ego=True, drive_id=drive_id),
                      actor("a", T, 80 + 10 * T, Y1, drive_id=drive_id)])


def write(folder: Path, tracks: pl.DataFrame, dt: float | None = 0.1, lanes: list[dict] = TWO_LANES) -> Path:
    """Canonical Parquet: tracks, drives (dt_s, the two-lane map; none when dt is None) and lanes."""
    folder.mkdir(parents=True, exist_ok=True)
    tracks.write_parquet(folder / "tracks.parquet")
    if dt is not None:
        ids = sorted(set(tracks["drive_id"].drop_nulls().cast(pl.String).to_list()))
        pl.DataFrame({"drive_id": ids, "dt_s": [dt] * len(ids), "map_id": ["road"] * len(ids)},
                     schema={"drive_id": pl.String, "dt_s": pl.Float64, "map_id": pl.String}
                     ).write_parquet(folder / "drives.parquet")
    pl.DataFrame(lanes).write_parquet(folder / "lanes.parquet")
    return folder


def run(tmp: Path, tracks: pl.DataFrame, dt: float | None = 0.1, lanes: list[dict] = TWO_LANES,
        max_gap: str = "0s") -> tuple[dict[str, dict], pl.DataFrame]:
    """Ingest and match follower_vehicle: (drives by id, matches). With max_gap = 0 (the default here) every
    missing frame shows as a split phase, which is what these tests look at."""
    db = tmp / "x.duckdb"
    ingest("parquet", [write(tmp / "in", tracks, dt, lanes)], db)
    result = match(db, scenarios=["follower_vehicle"], ego="recorded", overrides={"max_gap": max_gap})
    return {r["drive_id"]: r for r in result.drives.iter_rows(named=True)}, result.matches


def spans(matches: pl.DataFrame) -> list[tuple[int, int]]:
    return [(r["start_frame"], r["end_frame"]) for r in matches.sort("start_frame").iter_rows(named=True)]


def rejected(drives: dict[str, dict], drive_id: str) -> str:
    row = drives[drive_id]
    assert row["status"] == "rejected" and row["rows_rejected"] == row["rows_read"]
    return row["reject_reason"]


def test_the_clean_scene_matches(tmp_path):
    drives, matches = run(tmp_path, scene())
    assert drives["d1"]["status"] == "matched" and drives["d1"]["rows_rejected"] == 0
    assert spans(matches) == [(0, 50)]


# --- columns and types -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("wrong", "right", "hint"), [
    ("x", "x_m", " Did you mean 'x'?"),
    ("time_s", "t_s", " Did you mean 'time_s'?"),
    ("type", "kind", ""),
])
def test_missing_or_misnamed_column(tmp_path, wrong, right, hint):
    tracks = scene().rename({right: wrong})
    drives, _ = run(tmp_path, tracks)
    path = tmp_path / "in/tracks.parquet"
    assert rejected(drives, "in") == (f"{path}: missing column '{right}'.{hint}\n\n"
                                      "Hint: tracks need drive_id, actor_id, kind, t_s, x_m, y_m; see docs/tables.md.")


def test_text_in_a_numeric_column(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("y_m").cast(pl.String)))
    assert rejected(drives, "in") == (f"{tmp_path / 'in/tracks.parquet'}: column 'y_m' is String, not a number."
                                      "\n\nHint: write y_m as a float in the unit its name says.")


def test_text_in_the_boolean_is_ego(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("is_ego").cast(pl.String)))
    assert rejected(drives, "in") == (f"{tmp_path / 'in/tracks.parquet'}: column 'is_ego' is String, which does not "
                                      "convert to Boolean.\n\nHint: write is_ego as Boolean; see docs/tables.md.")


def test_integer_positions_are_numbers(tmp_path):
    drives, matches = run(tmp_path, scene().with_columns(pl.col("x_m").round().cast(pl.Int64)))
    assert drives["d1"]["status"] == "matched" and spans(matches) == [(0, 50)]


# --- wrong units ---------------------------------------------------------------------------------------------

def test_time_in_milliseconds_against_the_given_sample_period(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("t_s") * 1000))
    assert rejected(drives, "d1") == (
        f"{tmp_path / 'in/tracks.parquet'}: drive 'd1': consecutive samples of an actor are a median 1000 frames "
        "apart, so the timestamps do not step by dt_s = 0.1 s. Fix: write t_s in seconds and give the drive's true "
        "sample period as dt_s (drives.parquet), or leave dt_s out to derive it.")


def test_time_in_milliseconds_without_a_sample_period(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("t_s") * 1000), dt=None)
    assert rejected(drives, "d1") == (f"{tmp_path / 'in/tracks.parquet'}: drive 'd1': the sample period dt_s is "
                                      "100 s. Fix: write t_s in seconds (milliseconds divided by 1000) and dt_s in "
                                      "seconds.")


def test_positions_in_millimetres(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("x_m") * 1000, pl.col("y_m") * 1000))
    assert rejected(drives, "d1") == (f"{tmp_path / 'in/tracks.parquet'}: drive 'd1': actors move at a median "
                                      "10,000 m/s between samples. Fix: write x_m and y_m in metres (millimetres "
                                      "divided by 1000) and t_s in seconds.")


def test_heading_in_degrees(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(heading_rad=pl.lit(90.0)))
    assert rejected(drives, "d1") == (f"{tmp_path / 'in/tracks.parquet'}: drive 'd1': column 'heading_rad' reaches "
                                      "90, more than one turn (2 pi). Fix: write headings in radians (degrees * pi "
                                      "/ 180).")


@pytest.mark.parametrize("dt", [float("nan"), -0.1, 0.0])
def test_a_sample_period_that_is_not_a_positive_number(tmp_path, dt):
    drives, _ = run(tmp_path, scene(), dt=dt)
    assert rejected(drives, "d1") == (f"{tmp_path / 'in/drives.parquet'}: drive 'd1' has dt_s = {dt}. Fix: write the "
                                      "sample period in seconds (> 0), or leave it NULL to derive it from t_s.")


def test_a_broken_speed_value_is_derived_instead(tmp_path):
    tracks = scene().with_columns(speed_mps=pl.when(pl.col("t_s") == 1.0).then(1e9).otherwise(10.0))
    drives, matches = run(tmp_path, tracks)
    assert drives["d1"]["reject_reason"] == "2 speed_mps value(s) beyond +-1000 set to NULL and derived from positions"
    assert drives["d1"]["rows_rejected"] == 0 and spans(matches) == [(0, 50)]
    con = duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True)
    assert con.sql("select min(speed_mps), max(speed_mps) from tracks").fetchall()[0] == pytest.approx((10.0, 10.0))


# --- NaN, infinite and NULL values ----------------------------------------------------------------------------

@pytest.mark.parametrize("column", ["t_s", "x_m", "y_m"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf"), None])
def test_non_finite_rows_are_dropped_and_counted(tmp_path, column, value):
    bad = (pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)
    drives, matches = run(tmp_path, scene().with_columns(
        pl.when(bad).then(pl.lit(value, pl.Float64)).otherwise(pl.col(column)).alias(column)))
    row = drives["d1"]
    assert (row["rows_read"], row["rows_rejected"]) == (102, 1)
    assert row["reject_reason"] == "1 row(s) with a NULL, NaN or infinite t_s, x_m or y_m dropped"
    assert spans(matches) == [(0, 19), (21, 50)]  # the missing sample splits the follower's island


def test_nan_in_an_optional_column_is_derived(tmp_path):
    tracks = scene().with_columns(heading_rad=pl.when(pl.col("t_s") == 2.0).then(float("nan")).otherwise(0.0))
    drives, matches = run(tmp_path, tracks)
    assert drives["d1"]["rows_rejected"] == 0 and spans(matches) == [(0, 50)]


def test_rows_without_an_actor_id_are_dropped_and_counted(tmp_path):
    tracks = scene().with_columns(actor_id=pl.when(pl.col("t_s") < 1).then(None).otherwise(pl.col("actor_id")))
    drives, matches = run(tmp_path, tracks)
    row = drives["d1"]
    assert (row["rows_read"], row["rows_rejected"]) == (102, 20)
    assert row["reject_reason"] == "20 row(s) with a NULL actor_id, kind or frame dropped"
    assert spans(matches) == [(10, 50)]


def test_rows_without_a_drive_id_refuse_the_file(tmp_path):
    tracks = scene().with_columns(drive_id=pl.when(pl.col("t_s") < 1).then(None).otherwise(pl.col("drive_id")))
    drives, _ = run(tmp_path, tracks)
    assert rejected(drives, "in") == (f"{tmp_path / 'in/tracks.parquet'}: 20 row(s) have a NULL drive_id. Fix: give "
                                      "every row the drive it belongs to.")


# --- order, duplicates, gaps and jitter -------------------------------------------------------------------------

def test_unsorted_rows_give_the_same_tracks_and_matches(tmp_path):
    _, sorted_matches = run(tmp_path / "sorted", scene())
    drives, matches = run(tmp_path / "shuffled", scene().sample(fraction=1.0, shuffle=True, seed=7))
    assert drives["d1"]["rows_rejected"] == 0
    assert matches.drop("run_id").equals(sorted_matches.drop("run_id"))
    assert matches["match_id"].to_list() == sorted_matches["match_id"].to_list()
    stored = [duckdb.connect(str(tmp_path / f"{d}/x.duckdb"), read_only=True).sql(
        "select * from tracks order by actor_id, frame").pl() for d in ("sorted", "shuffled")]
    assert stored[0].equals(stored[1])


def test_exact_duplicate_rows_are_one_row(tmp_path):
    tracks = scene()
    drives, matches = run(tmp_path, pl.concat([tracks, tracks.filter(pl.col("t_s") < 1)]))
    row = drives["d1"]
    assert (row["rows_read"], row["rows_rejected"]) == (122, 20)
    assert row["reject_reason"] == "20 exact duplicate row(s) dropped"
    assert spans(matches) == [(0, 50)]


def test_a_duplicated_actor_is_one_actor(tmp_path):
    tracks = scene()
    drives, matches = run(tmp_path, pl.concat([tracks, tracks.filter(pl.col("actor_id") == "a")]))
    assert drives["d1"]["reject_reason"] == "51 exact duplicate row(s) dropped"
    assert spans(matches) == [(0, 50)]


def test_contradicting_rows_at_one_timestamp_are_all_dropped(tmp_path):
    tracks = scene()
    twin = tracks.filter((pl.col("actor_id") == "a") & (pl.col("t_s") == 2.5)).with_columns(pl.col("x_m") + 3)
    drives, matches = run(tmp_path, pl.concat([tracks, twin]))
    row = drives["d1"]
    assert (row["rows_read"], row["rows_rejected"]) == (103, 2)
    assert row["reject_reason"] == ("2 row(s) giving one actor different values at the same t_s dropped "
                                    "(e.g. actor_id 'a' at t_s = 2.5)")
    assert spans(matches) == [(0, 24), (26, 50)]  # neither position is trusted: the frame is missing


@pytest.mark.parametrize("who", ["a", "ego"])
def test_a_dropped_frame_is_missing_and_bridged_up_to_max_gap(tmp_path, who):
    tracks = scene().filter(~((pl.col("actor_id") == who) & (pl.col("t_s") == 3.0)))
    drives, matches = run(tmp_path / "a", tracks)
    assert drives["d1"]["rows_rejected"] == 0
    assert spans(matches) == [(0, 29), (31, 50)]  # with max_gap = 0 it splits the phase
    assert matches.sort("start_frame")["end_s"].to_list()[0] == pytest.approx(2.9)
    _, bridged = run(tmp_path / "b", tracks, max_gap="0.5s")  # the default: a missed detection is bridged
    assert spans(bridged) == [(0, 50)]


def test_dropped_frames_shorter_than_the_minimum_leave_no_match(tmp_path):
    # samples missing every 0.5 s: no island lasts the 1 s minimum
    tracks = scene().filter(~((pl.col("actor_id") == "a") & ((pl.col("t_s") * 10).round() % 5 == 4)))
    drives, matches = run(tmp_path, tracks)
    assert drives["d1"]["status"] == "no_match" and matches.is_empty()


def test_jittered_timestamps_fall_on_their_frames(tmp_path):
    jitter = np.random.default_rng(3).uniform(-0.04, 0.04, 102)  # less than half a sample period
    drives, matches = run(tmp_path, scene().with_columns(pl.col("t_s") + pl.Series(jitter)))
    assert drives["d1"]["rows_rejected"] == 0
    assert spans(matches) == [(0, 50)]
    stored = duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True).sql(
        "select frame, t_s from tracks where actor_id = 'a' order by frame").pl()
    assert stored["frame"].to_list() == list(range(51))
    assert stored["t_s"].to_list() == pytest.approx((T + jitter[51:]).tolist())  # t_s stays as recorded


def test_two_samples_in_one_frame_keep_the_nearer(tmp_path):
    tracks = scene()
    extra = tracks.filter((pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)).with_columns(
        pl.col("t_s") + 0.04, pl.col("x_m") + 0.4)  # rounds to frame 20 as well
    drives, matches = run(tmp_path, pl.concat([tracks, extra]))
    assert drives["d1"]["reject_reason"] == ("1 row(s) falling in a frame their actor already has dropped "
                                             "(the row nearest to frame * dt_s kept)")
    kept = duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True).sql(
        "select t_s from tracks where actor_id = 'a' and frame = 20").fetchall()
    assert kept == [(2.0,)]
    assert spans(matches) == [(0, 50)]


def test_a_sample_period_that_contradicts_the_timestamps(tmp_path):
    drives, _ = run(tmp_path, scene(), dt=0.05)  # the samples are 0.1 s apart: every other frame would be missing
    assert rejected(drives, "d1").startswith(f"{tmp_path / 'in/tracks.parquet'}: drive 'd1': consecutive samples of "
                                             "an actor are a median 2 frames apart")


# --- short and empty drives ---------------------------------------------------------------------------------------

def test_a_one_frame_track(tmp_path):
    tracks = pl.concat([scene(), actor("blip", np.array([2.0]), np.array([60.0]), Y1)])
    drives, matches = run(tmp_path, tracks)
    assert drives["d1"]["rows_rejected"] == 0 and spans(matches) == [(0, 50)]
    blip = duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True).sql(
        "select heading_rad, speed_mps, accel_mps2 from tracks where actor_id = 'blip'").fetchall()
    assert blip == [(0.0, None, None)]  # one sample has no speed: NULL, never 0


def test_a_one_frame_drive(tmp_path):
    drives, matches = run(tmp_path, scene().filter(pl.col("t_s") == 0.0), dt=None)
    assert drives["d1"]["status"] == "no_match" and drives["d1"]["rows_read"] == 2 and matches.is_empty()
    assert drives["d1"]["dt_s"] == 0.1  # one timestamp gives no step: 0.1 s, which a single frame does not use


def test_an_empty_tracks_file(tmp_path):
    drives, _ = run(tmp_path, scene().clear())
    assert rejected(drives, "in") == (f"{tmp_path / 'in/tracks.parquet'}: no rows. Fix: write the drive's track rows, "
                                      "or leave the file out.")


def test_a_drive_listed_without_track_rows(tmp_path):
    folder = write(tmp_path / "in", scene())
    pl.DataFrame({"drive_id": ["d1", "ghost"], "dt_s": [0.1, 0.1], "map_id": ["road", "road"]}).write_parquet(
        folder / "drives.parquet")
    ingest("parquet", [folder], tmp_path / "x.duckdb")
    drives = {r["drive_id"]: r for r in match(tmp_path / "x.duckdb", ego="recorded").drives.iter_rows(named=True)}
    assert drives["d1"]["status"] == "matched"
    assert rejected(drives, "ghost") == (f"{folder / 'tracks.parquet'}: drive 'ghost' is listed in drives.parquet but "
                                         "has no track rows. Fix: add its rows to tracks.parquet or remove it from "
                                         "drives.parquet.")


def test_a_drive_whose_every_row_is_bad(tmp_path):
    tracks = pl.concat([scene("good"), scene("bad").with_columns(x_m=pl.lit(float("nan")))])
    drives, matches = run(tmp_path, tracks)
    assert rejected(drives, "bad") == (f"{tmp_path / 'in/tracks.parquet'}: drive 'bad' has no usable track rows "
                                       "(102 row(s) with a NULL, NaN or infinite t_s, x_m or y_m dropped).")
    assert drives["good"]["status"] == "matched" and spans(matches) == [(0, 50)]


def test_an_empty_scenarionet_scene(tmp_path):
    with NUSCENES.open("rb") as f:
        scenario = pickle.load(f)  # our own bundled file, loaded to make a variant of it
    scenario["tracks"] = {}
    path = tmp_path / "empty.pkl"
    path.write_bytes(pickle.dumps(scenario))
    ingest("scenarionet", [path], tmp_path / "x.duckdb")
    (row,) = match(tmp_path / "x.duckdb", scenarios=["follower_vehicle"]).drives.iter_rows(named=True)
    assert row["status"] == "rejected"
    assert row["reject_reason"].startswith(f"{path}: ")


# --- kinds and coordinates ---------------------------------------------------------------------------------------

def test_an_unknown_kind_rejects_that_drive_only(tmp_path):
    tracks = pl.concat([scene("good"), scene("typo").with_columns(kind=pl.lit("vehicel"))])
    drives, matches = run(tmp_path, tracks)
    assert rejected(drives, "typo") == (
        f"{tmp_path / 'in/tracks.parquet'}: column 'kind' has unknown value(s) 'vehicel'. Did you mean 'vehicle'?\n\n"
        "Hint: kinds are the spec's evaluation_object_kind values: object, person, cyclist, vehicle, truck, trailer, "
        "fod, animal, sign, bus, motorcycle, emergency_vehicle, stationary_vehicle.")
    assert drives["good"]["status"] == "matched" and spans(matches) == [(0, 50)]


def test_enormous_coordinates_reject_the_drive(tmp_path):
    drives, _ = run(tmp_path, scene().with_columns(pl.col("x_m") + 1e15))
    assert rejected(drives, "d1") == (f"{tmp_path / 'in/tracks.parquet'}: drive 'd1' has no usable track rows (102 "
                                      "row(s) with |x_m| or |y_m| above 1e+08 m or |t_s| above 1e+10 s dropped).")


def test_one_enormous_coordinate_drops_its_row(tmp_path):
    bad = (pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)
    drives, matches = run(tmp_path, scene().with_columns(pl.when(bad).then(3e300).otherwise(pl.col("y_m")).alias("y_m")))
    assert drives["d1"]["rows_rejected"] == 1
    assert drives["d1"]["reject_reason"] == ("1 row(s) with |x_m| or |y_m| above 1e+08 m or |t_s| above 1e+10 s "
                                             "dropped")
    assert spans(matches) == [(0, 19), (21, 50)]


def test_a_time_too_large_for_a_frame_number(tmp_path):
    bad = (pl.col("actor_id") == "a") & (pl.col("t_s") == 2.0)
    drives, matches = run(tmp_path, scene().with_columns(pl.when(bad).then(1e300).otherwise(pl.col("t_s")).alias("t_s")))
    assert drives["d1"]["reject_reason"] == ("1 row(s) with |x_m| or |y_m| above 1e+08 m or |t_s| above 1e+10 s "
                                             "dropped")
    assert spans(matches) == [(0, 19), (21, 50)]


def test_utm_sized_coordinates_are_kept(tmp_path):
    # a southern-hemisphere UTM northing: large, and still metres
    north = 9_990_000.0
    lanes = [lane("L1", north, left="L2"), lane("L2", north + LANE_W, right="L1")]
    drives, matches = run(tmp_path, scene().with_columns(pl.col("y_m") + north), lanes=lanes)
    assert drives["d1"]["rows_rejected"] == 0 and spans(matches) == [(0, 50)]


# --- truncated, corrupt and unsafe files ------------------------------------------------------------------------

def _truncated_gzip(path: Path) -> None:
    path.write_bytes(NGSIM.read_bytes()[:4000])


def _truncated_xml(path: Path) -> None:
    path.write_bytes(gzip.decompress(NGSIM.read_bytes())[:20000])


def _truncated_pickle(path: Path) -> None:
    path.write_bytes(NUSCENES.read_bytes()[:5000])


def _garbage(path: Path) -> None:
    path.write_bytes(b"\x00\x01 not what the name says \xff" * 10)


XML_FIX = "Fix: re-export or re-download the file; gzip files must be complete."
PICKLE_FIX = "Fix: copy the ScenarioNet .pkl again from its source."


@pytest.mark.parametrize(("fmt", "good", "name", "spoil", "says", "fix"), [
    ("commonroad", NGSIM, "USA_cut_T-1.xml.gz", _truncated_gzip,
     "not a readable CommonRoad XML file (Compressed file ended before the end-of-stream marker was reached).", XML_FIX),
    ("commonroad", NGSIM, "USA_cut_T-1.xml", _truncated_xml, "not a readable CommonRoad XML file (no element found:",
     XML_FIX),
    ("commonroad", NGSIM, "USA_junk_T-1.xml", _garbage,
     "not a readable CommonRoad XML file (not well-formed (invalid token): line 1, column 0).", XML_FIX),
    ("scenarionet", NUSCENES, "cut.pkl", _truncated_pickle,
     "the file is truncated or not a pickle (UnpicklingError: pickle data was truncated).", PICKLE_FIX),
    ("scenarionet", NUSCENES, "junk.pkl", _garbage,
     "the file is truncated or not a pickle (UnpicklingError: invalid load key, '\\x00'.).", PICKLE_FIX),
])
def test_a_truncated_or_corrupt_file_is_rejected_and_the_good_one_still_matches(tmp_path, fmt, good, name, spoil,
                                                                                  says, fix):
    folder = tmp_path / "in"
    folder.mkdir()
    shutil.copy(good, folder / good.name)
    spoil(folder / name)
    ingest(fmt, [folder], tmp_path / "x.duckdb")
    result = match(tmp_path / "x.duckdb", scenarios=["follower_vehicle"], ego="every:10")
    drives = {r["source_path"]: r for r in result.drives.iter_rows(named=True)}
    bad = drives[str(folder / name)]
    assert bad["status"] == "rejected"
    assert bad["reject_reason"].startswith(f"{folder / name}: {says}")
    assert bad["reject_reason"].endswith(fix)
    # the NGSIM scene has followers; the nuScenes scene is read in full (every:10 numbers every kind that can be
    # under test since trucks and buses are SUTs, so it may pick an ego that has a follower)
    assert drives[str(folder / good.name)]["status"] in (("matched",) if fmt == "commonroad" else ("matched", "no_match"))
    assert drives[str(folder / good.name)]["rows_rejected"] == 0


@pytest.mark.parametrize("cut", [0.5, 0.9])
def test_a_truncated_parquet_file(tmp_path, cut):
    folder = write(tmp_path / "in", scene())
    data = (folder / "tracks.parquet").read_bytes()
    (folder / "tracks.parquet").write_bytes(data[: int(len(data) * cut)])
    ingest("parquet", [folder], tmp_path / "x.duckdb")
    (row,) = match(tmp_path / "x.duckdb").drives.iter_rows(named=True)
    assert row["status"] == "rejected"
    assert row["reject_reason"].startswith(f"{folder / 'tracks.parquet'}: not a readable Parquet file (")


class _RunsCode:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "the pickle ran code"))


def test_a_pickle_that_runs_code_is_refused_and_nothing_runs(tmp_path):
    marker = tmp_path / "ran.txt"
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"tracks": _RunsCode(marker)}))
    ingest("scenarionet", [path], tmp_path / "x.duckdb")
    (row,) = match(tmp_path / "x.duckdb", scenarios=["follower_vehicle"]).drives.iter_rows(named=True)
    assert not marker.exists()
    assert row["status"] == "rejected"
    assert row["reject_reason"] == (
        f"{path}: refused to load: the pickle asks for 'pathlib.Path.write_text', which is not a numpy array or a plain builtin. "
        "Fix: only load ScenarioNet files you trust, converted with numpy arrays and plain containers.")


# --- scenario files and parameters ---------------------------------------------------------------------------------

def test_a_scenario_inheritance_cycle(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\nextends = ["b"]\n')
    (tmp_path / "b.toml").write_text('name = "b"\nextends = ["c"]\n')
    (tmp_path / "c.toml").write_text('name = "c"\nextends = ["a"]\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario("b", tmp_path)
    assert str(e.value) == f"{tmp_path / 'b.toml'}: inheritance cycle b -> c -> a -> b.\n\nHint: remove one `extends` entry."


def test_an_unknown_key_in_a_parameter_of_a_scenario_file(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\nabstract = true\n[params.gap]\ntype = "length"\ndefualt = "5m"\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario("a", tmp_path)
    assert str(e.value) == (f"{tmp_path / 'a.toml'} [params.gap]: unknown key 'defualt'. Did you mean 'default'?\n\n"
                            "Hint: the keys here are default, description, type (docs/scenarios.md).")


def test_a_phase_limit_naming_an_unknown_parameter(tmp_path):
    (tmp_path / "a.toml").write_text(
        'name = "a"\n[params.max_len]\ntype = "time"\ndefault = "3s"\n'
        '[[phases]]\nname = "p"\nquery = "phases/follower_vehicle.sql"\nmax_duration = "max_lenght"\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario("a", tmp_path)
    assert str(e.value) == (f"{tmp_path / 'a.toml'} [[phases]] p: duration limit 'max_lenght' must name a time "
                            "parameter of the scenario. Did you mean 'max_len'?")


@pytest.mark.parametrize(("name", "value", "message"), [
    ("max_distance_from_cyclist", "5s", ("overrides['max_distance_from_cyclist']='5s': '5s' is a time, but this parameter is "
                                         "a length.\n\nHint: use a length unit such as 'm'.")),
    ("sut_minimal_speed", "5m", ("overrides['sut_minimal_speed']='5m': '5m' is a length, but this parameter is a speed.\n\n"
                                 "Hint: use a speed unit such as 'mps'.")),
    ("max_phase_duration", "5", ("overrides['max_phase_duration']='5': '5' has no unit; a time needs one.\n\n"
                                 "Hint: write it with a unit, e.g. \"5 s\".")),
])
def test_a_parameter_value_with_the_wrong_unit(name, value, message):
    with pytest.raises(UnitError) as e:
        resolve_scenarios(["cyclist_close_to_moving_sut"], {name: value})
    assert str(e.value) == message


# --- SQL text and quotes in values a user passes --------------------------------------------------------------------

HOSTILE = "x'); drop table tracks; --"


def _tables_intact(db: Path) -> None:
    con = duckdb.connect(str(db), read_only=True)
    assert con.sql("select count(*) from tracks").fetchall()[0][0] > 0
    assert con.sql("select count(*) from drive_inputs").fetchall()[0][0] > 0


def test_sql_in_ids_of_the_data_is_a_value(tmp_path):
    tracks = scene().with_columns(drive_id=pl.lit("d'1\"; drop table tracks; --"),
                                  actor_id=pl.col("actor_id") + "' or '1'='1")
    drives, matches = run(tmp_path, tracks)
    assert drives["d'1\"; drop table tracks; --"]["status"] == "matched"
    assert matches["actor_id"].to_list() == ["a' or '1'='1"]
    _tables_intact(tmp_path / "x.duckdb")


def test_sql_in_the_ego_option_is_a_value(tmp_path):
    db = tmp_path / "x.duckdb"
    ingest("parquet", [write(tmp_path / "in", scene())], db)
    result = match(db, scenarios=["follower_vehicle"], ego=HOSTILE)
    assert result.drives["status"].to_list() == ["no_ego"] and result.matches.is_empty()
    _tables_intact(db)


def test_sql_in_the_drive_option_is_a_value(tmp_path):
    db = tmp_path / "x.duckdb"
    ingest("parquet", [write(tmp_path / "in", scene())], db)
    with pytest.raises(ScenarioError) as e:
        match(db, scenarios=["follower_vehicle"], drives=[HOSTILE])
    assert str(e.value) == f"drives={HOSTILE!r}: no such drive in the file."
    _tables_intact(db)


@pytest.mark.parametrize(("name", "value"), [("kinds", HOSTILE), ("max_distance_from_cyclist", HOSTILE),
                                             (HOSTILE, "5m")])
def test_sql_in_a_parameter_is_refused(name, value):
    with pytest.raises((ScenarioError, UnitError)) as e:
        resolve_scenarios(["cyclist_close_to_moving_sut", "follower_vehicle"], {name: value})
    assert HOSTILE in str(e.value)


def test_sql_in_a_scenario_name_is_not_found(capsys, tmp_path):
    code = main(["match", "--db", str(tmp_path / "x.duckdb"), "--scenario", HOSTILE])
    assert code == 2
    assert capsys.readouterr().err == f"logiq-sql: error: scenario '{HOSTILE}' not found.\n"


def test_quotes_in_file_and_database_paths(tmp_path):
    folder = write(tmp_path / "it's \"here\"", scene())
    db = tmp_path / "o'brien \"db\".duckdb"
    ingest("parquet", [folder], db)
    result = match(db, scenarios=["follower_vehicle"], ego="recorded")
    assert result.drives["status"].to_list() == ["matched"]
    assert result.drives["source_path"].to_list() == [str(folder / "tracks.parquet")]


# --- one bad drive among good ones ----------------------------------------------------------------------------------

def test_bad_drives_are_rejected_with_their_reason_and_the_others_match(tmp_path):
    tracks = pl.concat([
        scene("good_1"),
        scene("unknown_kind").with_columns(kind=pl.lit("car")),
        scene("degrees").with_columns(heading_rad=pl.lit(180.0)),
        scene("all_nan").with_columns(y_m=pl.lit(math.nan)),
        scene("good_2"),
    ], how="diagonal")
    drives, matches = run(tmp_path, tracks)
    assert {d: r["status"] for d, r in drives.items()} == {
        "good_1": "matched", "good_2": "matched", "unknown_kind": "rejected", "degrees": "rejected",
        "all_nan": "rejected"}
    assert all(drives[d]["reject_reason"] for d in ("unknown_kind", "degrees", "all_nan"))
    assert sorted(matches["drive_id"].to_list()) == ["good_1", "good_2"]


def test_two_files_giving_one_drive_id(tmp_path):
    first = write(tmp_path / "first", scene())
    second = write(tmp_path / "second", scene().with_columns(pl.col("x_m") + 5))
    db = tmp_path / "x.duckdb"
    summary = ingest("parquet", [first, second, first], db)  # the same folder twice is one drive
    assert (summary.drives, summary.rejected, summary.rows) == (1, 1, 102)
    drives = {r["drive_id"]: r for r in match(db, scenarios=["follower_vehicle"], ego="recorded").drives.iter_rows(
        named=True)}
    assert drives["d1"]["status"] == "matched" and drives["d1"]["source_path"] == str(first / "tracks.parquet")
    clash = f"d1 ({second / 'tracks.parquet'})"
    assert rejected(drives, clash) == (f"{second / 'tracks.parquet'}: drive_id 'd1' was already read from "
                                       f"{first / 'tracks.parquet'} in this run. Fix: give every drive its own "
                                       "drive_id.")
    assert drives[clash]["rows_read"] == 102
    con = duckdb.connect(str(db), read_only=True)
    assert con.sql("select count(*) from tracks").fetchall() == [(102,)]
    assert con.sql("select count(*) from drive_inputs").fetchall() == [(2,)]


def test_a_drive_twice_in_one_batch_is_written_once(tmp_path):
    from logiq_sql.ingestion.ingest import write_drives
    from logiq_sql.ingestion.readers.parquet import read_parquet
    from logiq_sql.storage import db as logiq_db

    (drive,) = read_parquet(write(tmp_path / "in", scene()))
    con = logiq_db.connect(tmp_path / "x.duckdb")
    written = write_drives(con, [drive, drive])
    assert [kept for _, kept in written] == [102]
    assert con.sql("select count(*) from tracks").fetchall() == [(102,)]
    assert con.sql("select count(*) from drive_inputs").fetchall() == [(1,)]
    con.close()


@pytest.mark.parametrize(("env", "value", "message"), [
    ("LOGIQ_SQL_THREADS", "2; drop table tracks", "LOGIQ_SQL_THREADS='2; drop table tracks': write a whole number of "
                                                  "threads >= 1, or unset it."),
    ("LOGIQ_SQL_THREADS", "0", "LOGIQ_SQL_THREADS='0': write a whole number of threads >= 1, or unset it."),
    ("LOGIQ_SQL_MEMORY_LIMIT", "4GB'; drop table tracks; --", "LOGIQ_SQL_MEMORY_LIMIT=\"4GB'; drop table tracks; --\": "
                                                               "write a size such as 4GB or 512MiB."),
])
def test_environment_settings_are_checked_before_they_reach_duckdb(tmp_path, monkeypatch, capsys, env, value, message):
    monkeypatch.setenv(env, value)
    assert main(["ingest", "parquet", str(write(tmp_path / "in", scene())), "--db", str(tmp_path / "x.duckdb")]) == 2
    assert capsys.readouterr().err == f"logiq-sql: error: {message}\n"


def test_a_drive_rejected_on_reingest_keeps_no_old_matches(tmp_path):
    db = tmp_path / "x.duckdb"
    ingest("parquet", [write(tmp_path / "good", pl.concat([scene("d1"), scene("d2")]))], db)
    assert match(db, scenarios=["follower_vehicle"], ego="recorded").matches.height == 2
    ingest("parquet", [write(tmp_path / "bad", scene("d1").with_columns(kind=pl.lit("car")))], db)
    con = duckdb.connect(str(db), read_only=True)
    drives = {r[0]: r[1:] for r in con.sql("select drive_id, status, matches from drives").fetchall()}
    assert drives == {"d1": ("rejected", 0), "d2": ("matched", 1)}
    assert con.sql("select drive_id from matches").fetchall() == [("d2",)]
    assert con.sql("select count(*) from kpis").fetchall() == [(1,)]
    assert con.sql("select count(distinct match_id) from coverage_samples").fetchall() == [(1,)]
    hits = con.sql("select item, sum(hits) from coverage where scenario = 'follower_vehicle' group by item").fetchall()
    assert hits and all(n == 1 for _, n in hits)  # recounted: the rejected drive's match is gone from coverage


def test_a_reingested_drive_without_matches_keeps_no_old_relations(tmp_path):
    """The kept relation tables of a drive go with its old rows even when it had no match."""
    db = tmp_path / "x.duckdb"
    folder = write(tmp_path / "in", scene("d1"))
    ingest("parquet", [folder], db)
    # sut_cut_out relates every kind (the cyclist scenario alone would relate cyclists only: none here) and finds
    # no cut-out: the ego keeps its lane
    assert match(db, scenarios=["sut_cut_out"], ego="recorded", keep=True).matches.is_empty()

    def kept_rows() -> dict[str, int]:
        with duckdb.connect(str(db), read_only=True) as con:
            return {t: con.execute(f"select count(*) from {t} where drive_id = 'd1'").fetchall()[0][0]
                    for t in ("relations", "ego_lanes")}

    assert all(n > 0 for n in kept_rows().values())
    ingest("parquet", [folder], db)
    assert kept_rows() == {"relations": 0, "ego_lanes": 0}


@pytest.mark.parametrize(("limit", "shared", "whole"), [("2GiB", "1.0 GiB", "2.0 GiB"),
                                                      ("512MiB", "256.0 MiB", "512.0 MiB"),
                                                      ("3GB", "1.3 GiB", "2.7 GiB")])
def test_ingest_gives_duckdb_half_the_memory_limit(tmp_path, monkeypatch, limit, shared, whole):
    """The reader's chunk and the batch's localisation sit in Python beside DuckDB while ingesting, so DuckDB gets
    half of LOGIQ_SQL_MEMORY_LIMIT there (db.share_memory); match keeps the whole limit."""
    from logiq_sql.ingestion import ingest as ingestion
    from logiq_sql.storage import db as logiq_db

    monkeypatch.setenv("LOGIQ_SQL_MEMORY_LIMIT", limit)
    seen = []
    write_drives = ingestion.write_drives

    def spy(con, drives, *rest):
        seen.append(con.execute("select current_setting('memory_limit')").fetchall()[0][0])
        return write_drives(con, drives, *rest)

    monkeypatch.setattr(ingestion, "write_drives", spy)
    ingest("parquet", [write(tmp_path / "in", scene())], tmp_path / "x.duckdb")
    assert seen and set(seen) == {shared}
    with logiq_db.connect(tmp_path / "x.duckdb") as con:
        assert con.execute("select current_setting('memory_limit')").fetchall()[0][0] == whole
