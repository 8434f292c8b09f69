"""OpenSCENARIO and OpenLABEL exports (issue 20), validated against the published schemas in logiq_sql/outputs/schemas/.

The drive: a straight OpenDRIVE road written with scenariogeneration, an ego and a car following it 20 m behind
(a follower_vehicle match over the whole 6 s), ingested with ``ingest opendrive`` and matched.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest

from logiq_sql.cli import main
from logiq_sql.ingestion.ingest import ingest
from logiq_sql.matching.match import match
from logiq_sql.outputs.export.openlabel import export_openlabel, validate_openlabel
from logiq_sql.outputs.export.xosc import export_xosc, validate_xosc
from tests.helpers import Y1, actor, make_db, times

pytest.importorskip("xmlschema", reason="pip install 'logiq-sql[formats]'")
pytest.importorskip("jsonschema", reason="pip install 'logiq-sql[formats]'")
FOLLOWER = "follower_vehicle"


@pytest.fixture(scope="module")
def xodr_db(tmp_path_factory) -> Path:
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    xodr = pytest.importorskip("scenariogeneration.xodr")
    folder = tmp_path_factory.mktemp("export") / "drive"
    folder.mkdir()
    road = xodr.create_road(xodr.Line(500), id=1, left_lanes=1, right_lanes=2, lane_width=3.5)
    odr = xodr.OpenDrive("road")
    odr.add_road(road)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(folder / "road.xodr"))
    t = times(6.0)
    y = -1.75  # centre of the inner right lane (-1_1), driven along +x
    pl.concat([actor("ego", t, 100 + 10 * t, y, is_ego=True), actor("f", t, 80 + 10 * t, y),
               actor("walker", t, 50 + 0 * t, 8.0, kind="person", length=0.5, width=0.6)]).with_columns(
        heading_rad=pl.lit(0.0)).write_parquet(folder / "tracks.parquet")
    db = folder.parent / "x.duckdb"
    assert ingest("opendrive", [folder / "road.xodr"], db).drives == 1
    match(db, scenarios=[FOLLOWER])
    return db


def _match_id(db: Path) -> str:
    with duckdb.connect(str(db), read_only=True) as con:
        ((match_id,),) = con.sql("select match_id from matches").fetchall()
    return match_id


def test_xosc_replays_the_match_on_its_opendrive_map(xodr_db, tmp_path):
    match_id = _match_id(xodr_db)
    out = tmp_path / "scenarios" / "follow.xosc"
    done = export_xosc(xodr_db, match_id, out)
    validate_xosc(out)
    root = ET.parse(out).getroot()
    logic = root.find("RoadNetwork/LogicFile").get("filepath")
    assert (out.parent / logic).resolve() == (xodr_db.parent / "drive" / "road.xodr").resolve()
    assert {e.get("name"): e[0].tag for e in root.iter("ScenarioObject")} == {"ego": "Vehicle", "actor": "Vehicle"}
    with duckdb.connect(str(xodr_db), read_only=True) as con:
        start_s, ego_id, actor_id = con.sql(
            "select start_s, ego_id, actor_id from matches where match_id = $m", params={"m": match_id}).fetchall()[0]
        tracks = con.sql("select actor_id, t_s, x_m, y_m from tracks order by actor_id, frame").pl()
    assert (ego_id, actor_id) == ("ego", "f")
    for who, actor_id in (("ego", "ego"), ("actor", "f")):
        vertices = root.findall(f".//ManeuverGroup[@name='{who}_group']//Vertex")
        want = tracks.filter(pl.col("actor_id") == actor_id)
        assert len(vertices) == done.vertices[who] == want.height == 61
        got = np.array([[float(v.get("time")), float(v[0][0].get("x")), float(v[0][0].get("y"))] for v in vertices])
        assert np.abs(got - want.select(pl.col("t_s") - start_s, "x_m", "y_m").to_numpy()).max() < 1e-3
    teleports = {p.get("entityRef"): p.find(".//WorldPosition") for p in root.iter("Private")}
    assert float(teleports["actor"].get("x")) == pytest.approx(80.0)
    assert float(root.find("Storyboard/StopTrigger//SimulationTimeCondition").get("value")) == pytest.approx(6.0)


def test_xosc_of_a_match_on_another_map_references_no_logic_file(tmp_path):
    t = times(6.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, 80 + 10 * t, Y1)])
    match(db, scenarios=[FOLLOWER])
    out = tmp_path / "m.xosc"
    assert main(["export", "xosc", _match_id(db), "--db", str(db), "--out", str(out)]) == 0
    validate_xosc(out)
    root = ET.parse(out).getroot()
    assert root.find("RoadNetwork/LogicFile") is None
    assert "map: road (not an OpenDRIVE file; no LogicFile)" in root.find("FileHeader").get("description")


def test_xosc_of_an_unknown_match_is_a_clear_error(xodr_db, tmp_path, capsys):
    assert main(["export", "xosc", "nope", "--db", str(xodr_db), "--out", str(tmp_path / "x.xosc")]) == 2
    assert "match_id 'nope': no such match" in capsys.readouterr().err
    assert not (tmp_path / "x.xosc").exists()


def test_a_broken_xosc_fails_validation(xodr_db, tmp_path):
    out = tmp_path / "m.xosc"
    export_xosc(xodr_db, _match_id(xodr_db), out)
    out.write_text(out.read_text().replace("<CatalogLocations />", ""))
    with pytest.raises(Exception, match="CatalogLocations"):
        validate_xosc(out)


def test_openlabel_has_tags_objects_phases_and_kpis(xodr_db, tmp_path):
    assert main(["export", "openlabel", "--db", str(xodr_db), "--out", str(tmp_path / "labels")]) == 0
    files = sorted((tmp_path / "labels").iterdir())
    with duckdb.connect(str(xodr_db), read_only=True) as con:
        (drive_id,) = con.sql("select drive_id from drive_inputs").fetchall()[0]
        phases = con.sql("select phase, start_frame, end_frame from match_phases order by phase_index").fetchall()
        kpis = con.sql("select * from kpis").pl().to_dicts()[0]
        m = con.sql("select match_id, start_frame, end_frame from matches").fetchall()[0]
    assert [f.name for f in files] == [f"{drive_id}.json"]
    validate_openlabel(files[0])
    label = json.loads(files[0].read_text())["openlabel"]
    assert label["metadata"]["schema_version"] == "1.0.0" and label["metadata"]["name"] == drive_id
    assert label["tags"] == {"0": {"type": FOLLOWER, "tag_data": {"num": [{"name": "matches", "val": 1}]}}}
    objects = {o["name"]: o for o in label["objects"].values()}
    assert set(objects) == {"ego", "f"}  # the walker is in no match
    assert objects["ego"]["type"] == "vehicle" and objects["ego"]["frame_intervals"] == [
        {"frame_start": 0, "frame_end": 60}]
    assert {"name": "is_ego", "val": True} in objects["ego"]["object_data"]["boolean"]
    actions = list(label["actions"].values())
    scenario_action = actions[0]
    assert scenario_action["type"] == FOLLOWER
    assert scenario_action["frame_intervals"] == [{"frame_start": m[1], "frame_end": m[2]}]
    nums = {d["name"]: d["val"] for d in scenario_action["action_data"]["num"]}
    texts = {d["name"]: d["val"] for d in scenario_action["action_data"]["text"]}
    numeric_kpis = {k: v for k, v in kpis.items() if isinstance(v, float)}
    assert numeric_kpis and all(nums[k] == pytest.approx(v) for k, v in numeric_kpis.items())
    text_kpis = {k: v for k, v in kpis.items() if isinstance(v, str) and k not in ("match_id", "scenario")}
    assert texts["match_id"] == m[0] and text_kpis and all(texts[k] == v for k, v in text_kpis.items())
    assert not any(v is None for v in [*nums.values(), *texts.values()])  # NULL KPIs are left out
    assert [(a["type"], a["frame_intervals"][0]["frame_start"], a["frame_intervals"][0]["frame_end"])
            for a in actions[1:]] == phases
    relations = {r["type"]: r for r in label["relations"].values()}
    assert relations["is_ego_of"]["rdf_objects"] == [{"type": "action", "uid": "0"}]
    ego_uid = next(uid for uid, o in label["objects"].items() if o["name"] == "ego")
    assert relations["is_ego_of"]["rdf_subjects"] == [{"type": "object", "uid": ego_uid}]


def test_a_broken_openlabel_fails_validation(xodr_db, tmp_path):
    (path,) = export_openlabel(xodr_db, tmp_path)
    label = json.loads(path.read_text())
    label["openlabel"]["actions"]["0"]["frame_intervals"] = [{"frame_start": "zero"}]
    path.write_text(json.dumps(label))
    with pytest.raises(Exception, match="'zero' is not of type 'integer'"):
        validate_openlabel(path)


def test_openlabel_file_names_never_collide(tmp_path):
    t = times(2.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True, drive_id=d) for d in ("a/b", "a_b")])
    files = export_openlabel(db, tmp_path / "labels")
    assert len({f.name for f in files}) == 2 and files[1].name == "a_b.json"
    assert files[0].name.startswith("a_b-") and files[0].name.endswith(".json")
    for f in files:
        validate_openlabel(f)
    names = {json.loads(f.read_text())["openlabel"]["metadata"]["name"] for f in files}
    assert names == {"a/b", "a_b"}


def test_xosc_of_a_sumo_match_can_carry_its_network_as_opendrive(tmp_path):
    """The junction run's first 60 s: a follower_vehicle match exported with --convert-map references the
    network written as OpenDRIVE, and every trajectory vertex lies on a lane of that OpenDRIVE map (same frame)."""
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    import gzip
    import shutil

    import shapely

    from logiq_sql.ingestion.readers.opendrive import xodr_map

    junction = Path(__file__).parents[1] / "data" / "sumo" / "junction_s1"
    run = tmp_path / "run"
    run.mkdir()
    for name in ("network.net.xml.gz", "routes.rou.xml"):
        shutil.copy(junction / name, run / name)
    fcd = gzip.decompress((junction / "fcd.xml.gz").read_bytes())
    (run / "fcd.xml").write_bytes(fcd[: fcd.index(b'<timestep time="60.00"')] + b"</fcd-export>\n")
    db = tmp_path / "sumo.duckdb"
    assert ingest("sumo", [run], db).drives == 1
    match(db, scenarios=[FOLLOWER])
    with duckdb.connect(str(db), read_only=True) as con:
        match_id = con.sql("select match_id from matches order by match_id limit 1").fetchall()[0][0]
    plain, converted = tmp_path / "plain.xosc", tmp_path / "out" / "replay.xosc"
    export_xosc(db, match_id, plain)
    assert ET.parse(plain).getroot().find("RoadNetwork/LogicFile") is None
    assert main(["export", "xosc", match_id, "--db", str(db), "--out", str(converted), "--convert-map"]) == 0
    validate_xosc(converted)
    root = ET.parse(converted).getroot()
    assert root.find("RoadNetwork/LogicFile").get("filepath") == "replay.xodr"
    _, (lanes, *_) = xodr_map(converted.with_suffix(".xodr"))
    area = shapely.union_all(shapely.from_wkt(lanes["polygon_wkt"].to_numpy()))
    points = [shapely.Point(float(p.get("x")), float(p.get("y"))) for p in root.iter("WorldPosition")]
    assert len(points) > 20
    off = max(area.distance(p) for p in points)
    print(f"vertices {len(points)}, farthest from a lane {off:.3f} m")
    assert off < 0.5, off  # box centres of cars in their lanes
