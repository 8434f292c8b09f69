"""unprotected_left_turn_with_yield_and_traffic_light on real drives, phase by phase.

NGSIM Lankershim and Peachtree (CommonRoad 2020a, with traffic-light cycles) and the Argoverse 2 logs in
which the ego stops near a junction and turns left. Each condition that real data can decide is checked
against an independent computation from the raw files (shapely, the XML light cycle)."""

from __future__ import annotations

import gzip
import xml.etree.ElementTree as ET
from pathlib import Path

import duckdb
import polars as pl
import pytest
import shapely
from junction_helpers import left_turn_frames

from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.explain import explain
from logiq_sql.matching.match import match

DATA = Path(__file__).parents[1] / "data"
SCENARIO = "unprotected_left_turn_with_yield_and_traffic_light"
LANKER = DATA / "commonroad_ngsim/scenarios_2020a_with_traffic_lights/USA_Lanker-1_3_T-1.xml.gz"
PEACH = DATA / "commonroad_ngsim/scenarios_2020a_with_traffic_lights/USA_Peach-4_8_T-1.xml.gz"
MIAMI = "3b3570b4-7b0b-3268-a571-b0889dbf40b6"  # the ego stops in a junction, then turns left 80 degrees
PITTSBURGH = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"  # stops 1.5 m before a junction, turns left as the log ends
ONCOMING = "2357dba4-c8f6-40e7-aee3-6af6a2908521"  # passes the Miami ego while it stands in the junction
TABLES = ("phase_frames", "passages", "tracks")


@pytest.fixture(scope="module")
def ngsim(tmp_path_factory):
    db = tmp_path_factory.mktemp("ngsim_lt") / "ngsim.duckdb"
    ingest("commonroad", [LANKER, PEACH], db)
    return db, match(db, scenarios=[SCENARIO], ego="all"), left_turn_frames(db, "all", tables=TABLES)


@pytest.fixture(scope="module")
def av2(tmp_path_factory, ingested):
    db = ingested(tmp_path_factory.mktemp("av2_lt") / "av2.duckdb", "av2", [DATA / "av2"])
    return db, match(db, scenarios=[SCENARIO]), left_turn_frames(db, "recorded", tables=TABLES)


def test_ngsim_junction_entries_and_exits_agree_with_the_junction_polygons(ngsim):
    """passages: the centre is inside the intersection's polygon at the entry and exit frames, and outside
    at the frame before the entry and the frame after the exit (shapely on the raw positions)."""
    db, _, t = ngsim
    with duckdb.connect(str(db), read_only=True) as con:
        junctions = con.sql("select d.drive_id, j.junction_id, j.polygon_wkt from junctions j "
                            "join drive_inputs d on d.map_id = j.map_id").pl()
    passages = t["passages"].filter(pl.col("entry_observed") & pl.col("exit_observed"))
    assert passages.height >= 10
    edges = pl.concat([
        passages.select("drive_id", "actor_id", "junction_id", frame=f, expected=pl.lit(inside))
        for f, inside in ((pl.col("entry_frame") - 1, False), (pl.col("entry_frame"), True),
                          (pl.col("exit_frame"), True), (pl.col("exit_frame") + 1, False))])
    rows = (edges.join(t["tracks"], on=["drive_id", "actor_id", "frame"])
            .join(junctions, on=["drive_id", "junction_id"]))
    assert rows.height == edges.height
    inside = shapely.contains_xy(shapely.from_wkt(rows["polygon_wkt"].to_numpy()), rows["x_m"].to_numpy(),
                                 rows["y_m"].to_numpy())
    assert (inside == rows["expected"].to_numpy()).all()


def _cycle_state(xml: Path, light_id: str, frame: int) -> str:
    """The light's colour at ``frame`` from its <cycle> in the XML, computed here independently."""
    root = ET.fromstring(gzip.decompress(xml.read_bytes()))
    light = next(e for e in root.iter("trafficLight") if e.get("id") == light_id)
    cycle = light.find("cycle")
    elements = [(int(e.findtext("duration")), e.findtext("color")) for e in cycle.findall("cycleElement")]
    position = (frame - int(cycle.findtext("timeOffset") or 0)) % sum(d for d, _ in elements)
    for duration, colour in elements:
        if position < duration:
            return colour
        position -= duration
    raise AssertionError("unreachable")


def test_ngsim_light_states_follow_the_xml_cycles(ngsim):
    """light_state of the ego's movement equals the colour of that light's cycle in the file."""
    db, _, t = ngsim
    frames = t["phase_frames"].filter(pl.col("drive_id").str.starts_with("USA_Lanker-1_3")
                                      & pl.col("light_state").is_not_null())
    assert frames.height > 100
    with duckdb.connect(str(db), read_only=True) as con:
        lights = con.sql("select l.lane_id as entry_lane_id, l.light_id, l.direction from traffic_lights l "
                         "join drive_inputs d on d.map_id = l.map_id where d.drive_id like 'USA_Lanker-1_3%'").pl()
    governed = (frames.join(t["passages"].rename({"actor_id": "ego_id", "passage": "ego_passage"}),
                            on=["drive_id", "ego_id", "ego_passage"])
                .join(lights, on="entry_lane_id")
                .filter(pl.col("direction").is_null() | pl.col("direction").str.contains(pl.col("turn"))))
    sample = governed.unique(["light_id", "frame"]).sort("light_id", "frame").gather_every(7)
    assert sample.height > 10
    for r in sample.iter_rows(named=True):
        expected = _cycle_state(LANKER, r["light_id"], r["frame"])
        assert r["light_state"] == ("green" if expected == "green" else r["light_state"])
        assert (r["light_state"] == "green") == (expected == "green"), r


def test_ngsim_has_no_left_turn_yield_and_explain_says_why(ngsim):
    """The 2020a scenes are 1-5 s long: no car is seen entering and leaving a junction on a left turn, so
    no match, and explain names the missing left turn for every pair."""
    db, result, t = ngsim
    assert result.matches.is_empty()
    assert not t["passages"].filter(pl.col("turn") == "left").height
    frames = t["phase_frames"]
    assert frames.height > 1000
    assert frames.select(pl.col("phase_4").any()).item() is False
    drive = frames["drive_id"][0]
    ego = frames.filter(pl.col("drive_id") == drive)["ego_id"][0]
    found = explain(db, SCENARIO, drive, ego)
    assert found.pairs.height > 0
    for failed in found.pairs["failed"]:
        assert any(f.startswith("ego_turns_left is false") for f in failed)


def test_av2_stop_then_left_turn_logs_do_not_match(av2):
    """The Miami and Pittsburgh egos stop near a junction and turn left; AV2 maps have no traffic lights,
    so stop_in_green_light can never be claimed and explain says so."""
    db, result, t = av2
    assert result.drives.height == 5 and result.matches.is_empty()
    ego_passages = t["passages"].filter(pl.col("actor_id") == "ego")
    miami = ego_passages.filter(pl.col("drive_id") == MIAMI).row(0, named=True)
    assert miami["turn"] == "left" and miami["turn_from_map"] is None  # AV2 gives no turns: from the heading
    pittsburgh = ego_passages.filter(pl.col("drive_id") == PITTSBURGH).row(0, named=True)
    assert pittsburgh["exit_observed"] is False and pittsburgh["turn"] is None  # the log ends mid-turn
    for drive in (MIAMI, PITTSBURGH):
        found = explain(db, SCENARIO, drive, "recorded")
        assert (found.pairs["phases_reached"] == 0).all()
        for failed in found.pairs["failed"]:
            assert any(f.startswith("light_green is false: light_state = NULL") for f in failed)


def test_av2_miami_ego_does_yield_to_an_oncoming_car(av2):
    """Phase by phase, the Miami log is a yield: the ego stands 3.7 m into the junction (3.5-5.0 s) while an
    oncoming car passes 2-3 m to its left at 12 m/s; every phase but the traffic-light one holds for it."""
    _, _, t = av2
    pair = t["phase_frames"].filter((pl.col("drive_id") == MIAMI) & (pl.col("actor_id") == ONCOMING))
    assert pair["traversal_relative_direction"].unique().to_list() == ["opposite_to_parallel"]
    assert pair.select(pl.col("phase_2").any(), pl.col("phase_3").any(), pl.col("phase_4").any()).row(0) == (
        True, True, True)
    stood = pair.filter(pl.col("ego_stopped") & pl.col("ego_yields"))
    assert stood.height > 10 and stood["ego_offset_from_junction_start_m"].is_between(0, 10).all()
    assert not pair["light_green"].any() and pair["light_state"].is_null().all()
    assert pair["pet_s"].drop_nulls().unique().to_list()[0] > 0
