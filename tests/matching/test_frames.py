"""match_frames: frames in, frames out, no file. The same results as writing the frames as canonical Parquet,
ingesting and matching them; the same messages for bad input; Polars LazyFrames and Arrow tables as inputs; and
without a map, the scenarios that need none run while the others say why."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest

from logiq_sql import InputError, ingest, match, match_frames
from logiq_sql.spec.scenario import list_scenarios
from logiq_sql.storage import db
from tests.helpers import TWO_LANES, Y1, actor, times

DATA = Path(__file__).parents[1] / "data"
NUSCENES = DATA / "nuscenes_mini_scenarionet"
LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"
MAP_TABLES = ("lanes", "lane_successors", "junctions", "traffic_lights", "traffic_light_states")


def canonical_frames(path: Path) -> dict[str, pl.DataFrame]:
    """The canonical tables of an ingested file as frames: what a user's own loader would hand over."""
    con = db.connect(path)
    try:
        frames = {t: con.sql(f"select * from {t} order by all").pl() for t in ("tracks", *MAP_TABLES)}
        frames["drives"] = con.sql("select drive_id, dt_s, map_id, ego_actor_id from drive_inputs "
                                   "where status = 'ingested' order by drive_id").pl()
    finally:
        con.close()
    return frames


def via_files(tmp: Path, frames: dict[str, pl.DataFrame], **kwargs):
    """The file route: the frames as canonical Parquet, ingest parquet, match."""
    folder = tmp / "canonical"
    folder.mkdir()
    for name, frame in frames.items():
        frame.write_parquet(folder / f"{name}.parquet")
    ingest("parquet", [folder], tmp / "files.duckdb")
    return match(tmp / "files.duckdb", **kwargs)


def assert_same_results(files, frames) -> None:
    assert frames.matches.height > 0
    assert frames.matches.drop("run_id").equals(files.matches.drop("run_id"))
    for table in ("match_phases", "kpis", "coverage"):
        assert getattr(frames, table).equals(getattr(files, table)), table
    kept = ["drive_id", "map_id", "dt_s", "ego_actor_id", "rows_read", "rows_rejected", "reject_reason", "status",
            "matches", "matches_per_scenario"]
    assert frames.drives.select(kept).equals(files.drives.select(kept))
    assert set(frames.drives["source_format"]) == {"frames"}


@pytest.fixture(scope="module")
def nuscenes(tmp_path_factory):
    path = tmp_path_factory.mktemp("frames") / "nuscenes.duckdb"
    ingest("scenarionet", [NUSCENES], path)
    return canonical_frames(path)


@pytest.fixture(scope="module")
def junction(tmp_path_factory, ingested):
    return canonical_frames(ingested(tmp_path_factory.mktemp("frames") / "junction.duckdb", "sumo",
                                     [DATA / "sumo/junction_s1"]))


SETTINGS = {"overrides": {"max_distance_from_cyclist": "6m"},
            "scenarios": ["cyclist_close_to_moving_sut", "follower_vehicle", "sut_cut_out"]}


def test_same_results_as_ingest_and_match_of_the_same_drives(nuscenes, tmp_path):
    files = via_files(tmp_path, nuscenes, **SETTINGS)
    frames = match_frames(nuscenes["tracks"], **{k: v for k, v in nuscenes.items() if k != "tracks"}, **SETTINGS)
    assert_same_results(files, frames)
    assert set(frames.matches["scenario"]) == {"follower_vehicle", "cyclist_close_to_moving_sut"}
    assert frames.scenarios["ran"].all() and frames.drive_scenarios.height == 3 * frames.drives.height


def test_every_scenario_runs_or_says_why_not(nuscenes):
    result = match_frames(nuscenes["tracks"], **{k: v for k, v in nuscenes.items() if k != "tracks"})
    # the nuScenes scenes have lanes, but no junction polygons and no traffic lights
    ((scenario, ran, reason),) = result.scenarios.filter(~pl.col("ran")).rows()
    assert scenario == LEFT_TURN and reason == (
        f"{LEFT_TURN} cannot run without junctions, traffic_light_states, traffic_lights: "
        "queries/phases/unprotected_left_turn_frames.sql reads crossing_pairs (built from lanes and junctions), "
        "junction_frames (built from lanes and junctions), passages (built from lanes and junctions), "
        "traffic_light_states, traffic_lights. Fix: pass junctions=, traffic_light_states=, traffic_lights= to "
        "match_frames (columns in docs/tables.md).")
    assert result.scenarios.height == len(list_scenarios()) and set(result.drive_scenarios["scenario"]) == set(
        result.scenarios.filter(pl.col("ran"))["scenario"])


def test_the_left_turn_on_the_sumo_junction(junction, tmp_path):
    files = via_files(tmp_path, junction, scenarios=[LEFT_TURN], ego="every:40")
    frames = match_frames(junction["tracks"], **{k: v for k, v in junction.items() if k != "tracks"},
                          scenarios=[LEFT_TURN], ego="every:40")
    assert_same_results(files, frames)
    assert frames.scenarios.rows() == [(LEFT_TURN, True, None)]


def test_lazy_frames_and_arrow_tables(nuscenes):
    maps = {k: v for k, v in nuscenes.items() if k != "tracks"}
    eager = match_frames(nuscenes["tracks"], **maps, scenarios=["follower_vehicle"])
    lazy = match_frames(nuscenes["tracks"].lazy(), **{k: v.lazy() for k, v in maps.items()},
                        scenarios=["follower_vehicle"])
    arrow = match_frames(nuscenes["tracks"].to_arrow(), **{k: v.to_arrow() for k, v in maps.items()},
                         scenarios=["follower_vehicle"])
    assert eager.matches.height > 0
    for other in (lazy, arrow):
        assert other.matches.drop("run_id").equals(eager.matches.drop("run_id"))
        assert other.kpis.equals(eager.kpis)


def test_without_a_map_the_scenarios_that_need_none_still_run(nuscenes):
    with_map = match_frames(nuscenes["tracks"], **{k: v for k, v in nuscenes.items() if k != "tracks"}, **SETTINGS)
    bare = match_frames(nuscenes["tracks"], overrides=SETTINGS["overrides"])
    cyclist = pl.col("scenario") == "cyclist_close_to_moving_sut"
    assert bare.matches.height > 0
    assert bare.matches.drop("run_id").equals(with_map.matches.filter(cyclist).drop("run_id"))
    reasons = dict(bare.scenarios.filter(~pl.col("ran")).select("scenario", "reason").iter_rows())
    # every scenario but the cyclist's reads the lanes
    assert sorted(reasons) == sorted(s.name for s in list_scenarios() if s.name != "cyclist_close_to_moving_sut")
    assert reasons["follower_vehicle"] == (
        "follower_vehicle cannot run without lanes: queries/phases/follower_vehicle_frames.sql reads ego_lanes (built "
        "from lanes), ego_road (built from lanes), lane_successors (built from lanes); queries/phases/"
        "follower_vehicle.sql reads ego_road (built from lanes), lane_successors (built from lanes). Fix: pass lanes= "
        "to match_frames (columns in docs/tables.md).")
    assert reasons[LEFT_TURN].startswith(f"{LEFT_TURN} cannot run without lanes, junctions, traffic_light_states, "
                                         "traffic_lights: ")
    assert set(bare.drive_scenarios["scenario"]) == {"cyclist_close_to_moving_sut"}


def test_no_scenario_can_run(nuscenes):
    result = match_frames(nuscenes["tracks"], scenarios=["follower_vehicle"])
    assert result.matches.is_empty() and result.kpis.is_empty() and result.scenarios["ran"].to_list() == [False]
    assert result.drives["status"].unique().to_list() == ["not_matched"] and result.drives.height == 4


# --- bad input: the messages of ingest, with the frame named where ingest names the file ---------------------

T = times(5)


def scene(drive_id: str = "d1") -> pl.DataFrame:
    return pl.concat([actor("ego", T, 100 + 10 * T, Y1, is_ego=True, drive_id=drive_id),
                      actor("a", T, 80 + 10 * T, Y1, drive_id=drive_id)])


def drives_of(tracks: pl.DataFrame, dt: float | None = 0.1) -> pl.DataFrame:
    ids = sorted(set(tracks["drive_id"].drop_nulls().cast(pl.String).to_list()))
    return pl.DataFrame({"drive_id": ids, "dt_s": [dt] * len(ids), "map_id": ["road"] * len(ids)},
                        schema={"drive_id": pl.String, "dt_s": pl.Float64, "map_id": pl.String})


BAD = {
    "misnamed column": scene().rename({"x_m": "x"}),
    "no kind": scene().rename({"kind": "type"}),
    "text positions": scene().with_columns(pl.col("y_m").cast(pl.String)),
    "text is_ego": scene().with_columns(pl.col("is_ego").cast(pl.String)),
    "rows of no drive": scene().with_columns(drive_id=pl.when(pl.col("t_s") > 4).then(None).otherwise(pl.col("drive_id"))),
    "unknown kind": pl.concat([scene("d1"), scene("d2").with_columns(kind=pl.lit("car"))]),
    "milliseconds": scene().with_columns(pl.col("t_s") * 1000),
    "degrees": scene().with_columns(heading_rad=pl.lit(90.0)),
    "millimetres": scene().with_columns(pl.col("x_m") * 1000, pl.col("y_m") * 1000),
    "NaN rows": scene().with_columns(x_m=pl.when(pl.col("t_s") == 1.0).then(float("nan")).otherwise(pl.col("x_m"))),
    "contradicting rows": pl.concat([scene(), scene().filter(pl.col("t_s") == 2.0).with_columns(pl.col("x_m") + 1)]),
    "two egos": scene().with_columns(is_ego=pl.lit(True)),
}
# ingest refuses the whole file in these cases (match_frames raises); in the others it rejects or trims a drive
REFUSED = {"misnamed column", "no kind", "text positions", "text is_ego", "rows of no drive"}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_gets_the_ingest_message(case, tmp_path):
    tracks = BAD[case]
    drives = drives_of(tracks)
    lanes = pl.DataFrame(TWO_LANES)
    folder = tmp_path / "in"
    folder.mkdir()
    tracks.write_parquet(folder / "tracks.parquet")
    drives.write_parquet(folder / "drives.parquet")
    lanes.write_parquet(folder / "lanes.parquet")
    ingest("parquet", [folder], tmp_path / "x.duckdb")
    files = match(tmp_path / "x.duckdb", scenarios=["follower_vehicle"], ego="recorded").drives

    def named_as_frames(text: str | None) -> str | None:
        if text is None:
            return None
        return text.replace(str(folder / "tracks.parquet"), "tracks").replace(str(folder / "drives.parquet"), "drives")

    assert (files["drive_id"].to_list() == ["in"]) == (case in REFUSED)
    if case in REFUSED:  # ingest refused the whole file: match_frames raises the same message
        with pytest.raises(InputError) as refused:
            match_frames(tracks, drives=drives, lanes=lanes, scenarios=["follower_vehicle"], ego="recorded")
        assert str(refused.value) == named_as_frames(files["reject_reason"][0])
        return
    frames = match_frames(tracks, drives=drives, lanes=lanes, scenarios=["follower_vehicle"], ego="recorded").drives
    kept = ["drive_id", "status", "rows_read", "rows_rejected", "matches"]
    assert frames.select(kept).equals(files.select(kept))
    assert frames["reject_reason"].to_list() == [named_as_frames(r) for r in files["reject_reason"]]
    assert frames["reject_reason"].drop_nulls().len() > 0


def test_a_drive_listed_without_track_rows_is_rejected_not_forgotten():
    tracks = scene()
    drives = pl.DataFrame({"drive_id": ["d1", "ghost"], "dt_s": [0.1, 0.1], "map_id": ["road", "road"]})
    result = match_frames(tracks, drives=drives, lanes=pl.DataFrame(TWO_LANES), scenarios=["follower_vehicle"])
    ghost = result.drives.filter(pl.col("drive_id") == "ghost").row(0, named=True)
    assert ghost["status"] == "rejected"
    assert ghost["reject_reason"] == ("tracks: drive 'ghost' is listed in drives but has no track rows. Fix: add its "
                                      "rows to tracks or remove it from drives.")


def test_one_map_needs_no_drives_table_several_do():
    tracks, lanes = scene(), pl.DataFrame(TWO_LANES)
    alone = match_frames(tracks, lanes=lanes, scenarios=["follower_vehicle"], ego="recorded")
    assert alone.drives["map_id"].to_list() == ["road"] and alone.matches.height == 1
    two_maps = pl.concat([lanes, lanes.with_columns(map_id=pl.lit("other"))])
    with pytest.raises(InputError, match=r"lanes: holds 2 maps \(other, road\) and drive 'd1' does not say which it "
                                         r"is on. Fix: pass drives= with a map_id for every drive."):
        match_frames(tracks, lanes=two_maps)


def test_a_map_table_missing_a_column():
    with pytest.raises(InputError, match=r"^lanes: missing column 'polygon_wkt'. Did you mean 'polygon'\?"):
        match_frames(scene(), lanes=pl.DataFrame(TWO_LANES).rename({"polygon_wkt": "polygon"}))


def test_not_a_table():
    with pytest.raises(InputError, match=r"tracks: a dict is not a table. Fix: pass a Polars DataFrame or LazyFrame "
                                         r"or an Arrow table"):
        match_frames({"drive_id": ["d1"]})


def test_no_file_is_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # DuckDB would put a file or its spill folder here, relative to the working folder
    result = match_frames(scene(), lanes=pl.DataFrame(TWO_LANES), scenarios=["follower_vehicle"], ego="recorded")
    assert result.matches.height == 1 and list(tmp_path.iterdir()) == []
