"""The SUMO reader, checked against the raw files of the bundled runs (tests/data/sumo, made by logiq-sql simulate).

motorway_s1: 2 simulated minutes of the 3.5 km motorway (seed 1); junction_s1: 5 minutes of the signalised 4-way
junction (seed 1). The raw FCD is parsed independently with ElementTree once, to check ``read_fcd``; the other
checks compare the canonical tables with ``read_fcd``'s raw columns and with the network XML.
"""

from __future__ import annotations

import gzip
import math
import re
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pytest
import shapely

from logiq_sql import ingest
from logiq_sql.cli import main
from logiq_sql.core.errors import InputError, LogiqError
from logiq_sql.ingestion.readers import sumo as sumo_reader
from logiq_sql.ingestion.readers.sumo import read_fcd, read_sumo, read_vtypes, xml_records

DATA = Path(__file__).parents[1] / "data" / "sumo"
MOTORWAY, JUNCTION = DATA / "motorway_s1", DATA / "junction_s1"


def _net(run: Path) -> ET.Element:
    return ET.fromstring(gzip.decompress((run / "network.net.xml.gz").read_bytes()))


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sumo") / "sumo.duckdb"
    summary = ingest("sumo", [DATA], path)  # a folder of run folders
    assert (summary.drives, summary.rejected, summary.rows_rejected) == (2, 0, 0)
    return path


def _sql(db: Path, query: str, **params) -> pl.DataFrame:
    with duckdb.connect(str(db), read_only=True) as con:
        return con.sql(query, params=params or None).pl()


def _fcd(run: Path) -> pl.DataFrame:
    return read_fcd(run / "fcd.xml.gz").with_columns(
        frame=(pl.col("t_s") / 0.1).round().cast(pl.Int64), actor_id=pl.col("vehicle_id"))


# -------------------------------------------------------------------------------------------------- raw FCD

def test_read_fcd_matches_an_elementtree_parse(monkeypatch):
    rows = []
    with gzip.open(JUNCTION / "fcd.xml.gz") as f:
        for _, el in ET.iterparse(f):
            if el.tag == "timestep":
                t = float(el.get("time"))
                rows += [(t, v.get("id"), v.get("type"), float(v.get("x")), float(v.get("y")),
                          float(v.get("angle")), float(v.get("speed")), float(v.get("acceleration")), v.get("lane"),
                          float(v.get("pos")), v.get("leaderID") or None, float(v.get("leaderGap")),
                          float(v.get("leaderSpeed"))) for v in el.iter("vehicle")]
                el.clear()
    S, F = pl.String, pl.Float64
    expected = pl.DataFrame(rows, orient="row", schema={
        "t_s": F, "vehicle_id": S, "type_id": S, "x_m": F, "y_m": F, "angle_deg": F, "speed_mps": F,
        "accel_mps2": F, "lane_id": S, "lane_pos_m": F, "leader_id": S, "leader_gap_m": F,
        "leader_speed_mps": F}).with_columns(
        pl.when(pl.col("leader_id").is_not_null()).then(pl.col(c)).alias(c)
        for c in ("leader_gap_m", "leader_speed_mps"))
    got = read_fcd(JUNCTION / "fcd.xml.gz")
    assert got.height == len(rows) > 100_000
    assert got.equals(expected)
    monkeypatch.setattr(sumo_reader, "CHUNK_BYTES", 100_000)  # 250 pieces: timesteps span the cuts
    assert read_fcd(JUNCTION / "fcd.xml.gz").equals(expected)
    assert got["leader_id"].null_count() > 0  # "" and -1 became NULL, never a sentinel
    assert (got["leader_gap_m"].drop_nulls() >= 0).all()


def test_read_vtypes_with_a_distribution_and_defaults():
    vt = {r["type_id"]: r for r in read_vtypes(MOTORWAY).to_dicts()}
    assert (vt["truck"]["vclass"], vt["truck"]["kind"], vt["truck"]["length_m"], vt["truck"]["width_m"]) == (
        "truck", "truck", 16.5, 2.55)  # a <vTypeDistribution> member
    assert (vt["aggressive"]["kind"], vt["aggressive"]["length_m"]) == ("vehicle", 4.5)
    assert (vt["DEFAULT_BIKETYPE"]["length_m"], vt["DEFAULT_BIKETYPE"]["width_m"]) == (1.6, 0.65)
    bike = {r["type_id"]: r for r in read_vtypes(JUNCTION).to_dicts()}["bike"]
    assert (bike["vclass"], bike["kind"]) == ("bicycle", "cyclist")


def test_vclass_default_sizes(tmp_path):
    (tmp_path / "t.rou.xml").write_text('<routes><vType id="lorry" vClass="truck"/><vType id="plain"/>'
                                        '<vType id="ped" vClass="pedestrian"/><vType id="cop" vClass="emergency"/>'
                                        "</routes>")
    vt = {r["type_id"]: r for r in read_vtypes(tmp_path).to_dicts()}
    assert (vt["lorry"]["length_m"], vt["lorry"]["width_m"], vt["lorry"]["kind"]) == (7.1, 2.4, "truck")
    assert (vt["plain"]["vclass"], vt["plain"]["length_m"], vt["plain"]["width_m"]) == ("passenger", 5.0, 1.8)
    assert vt["ped"]["kind"] == "person" and vt["cop"]["kind"] == "emergency_vehicle"


# ----------------------------------------------------------------------------------------------- drives

def test_every_drive_is_accounted_for(db):
    drives = _sql(db, "select * from drive_inputs order by drive_id")
    assert drives["drive_id"].to_list() == ["junction_s1", "motorway_s1"]
    for d in drives.iter_rows(named=True):
        run = DATA / d["drive_id"]
        assert d["source_format"] == "sumo" and d["source_path"] == str(run) and d["status"] == "ingested"
        assert d["dt_s"] == 0.1 and d["ego_actor_id"] is None and d["reject_reason"] is None
        assert d["rows_read"] == zlib_count(run) and d["rows_rejected"] == 0
        assert d["map_id"].startswith("sumo-") and "SUMO" in d["attribution"]
    assert drives["map_id"].n_unique() == 2
    assert _sql(db, "select count(*) as n from tracks where is_ego")["n"][0] == 0


def zlib_count(run: Path) -> int:
    return gzip.decompress((run / "fcd.xml.gz").read_bytes()).count(b"<vehicle ")


def test_same_network_same_map_id(tmp_path):
    copy = tmp_path / "again"
    shutil.copytree(JUNCTION, copy)
    raw = gzip.decompress((copy / "network.net.xml.gz").read_bytes())
    # netconvert's header comment (date, input paths) differs between builds of one network: not part of the map
    (copy / "network.net.xml.gz").write_bytes(gzip.compress(raw.replace(b"<!-- generated on", b"<!-- built on")))
    ((a,), (b,)) = list(read_sumo(JUNCTION)), list(read_sumo(copy))
    assert a.map_id == b.map_id and a.lanes.equals(b.lanes)


# ----------------------------------------------------------------------------------------------- tracks

@pytest.mark.parametrize("run", [MOTORWAY, JUNCTION], ids=lambda r: r.name)
def test_centre_and_heading_from_front_bumper_and_navigation_angle(db, run):
    tracks = _sql(db, "select * from tracks where drive_id = $d", d=run.name)
    fcd = _fcd(run).select("actor_id", "frame", fcd_t="t_s", front_x="x_m", front_y="y_m", angle="angle_deg",
                           fcd_speed="speed_mps", fcd_accel="accel_mps2")
    both = tracks.join(fcd, on=["actor_id", "frame"], how="full", coalesce=True)
    assert both.height == tracks.height == fcd.height  # one track row per FCD row, and no other
    h = both["heading_rad"].to_numpy()
    assert ((h > -math.pi) & (h <= math.pi)).all()
    expected = np.radians(90 - both["angle"].to_numpy())
    assert np.allclose(np.cos(h), np.cos(expected), atol=1e-12) and np.allclose(np.sin(h), np.sin(expected),
                                                                                atol=1e-12)
    half = both["length_m"].to_numpy() / 2
    # the centre moved forward by half the length along the heading is SUMO's front bumper
    assert np.abs(both["x_m"].to_numpy() + half * np.cos(h) - both["front_x"].to_numpy()).max() < 1e-9
    assert np.abs(both["y_m"].to_numpy() + half * np.sin(h) - both["front_y"].to_numpy()).max() < 1e-9
    assert (both["speed_mps"] == both["fcd_speed"]).all() and (both["accel_mps2"] == both["fcd_accel"]).all()
    assert (both["t_s"] == both["fcd_t"]).all()


def test_compass_directions(db):
    tracks = _sql(db, "select * from tracks where drive_id = 'junction_s1'")
    fcd = _fcd(JUNCTION).select("actor_id", "frame", "angle_deg")
    both = tracks.join(fcd, on=["actor_id", "frame"])
    for angle, heading in ((0.0, math.pi / 2), (90.0, 0.0), (180.0, -math.pi / 2), (270.0, math.pi)):
        h = both.filter(pl.col("angle_deg") == angle)["heading_rad"]
        assert h.len() > 100 and np.allclose(h.to_numpy(), heading), angle  # west is +pi, never -pi


def test_kinds_and_sizes_from_the_vehicle_types(db):
    tracks = _sql(db, "select drive_id, actor_id, kind, length_m, width_m from tracks")
    types = pl.concat([_fcd(run).select(pl.lit(run.name).alias("drive_id"), "actor_id", "type_id")
                       for run in (MOTORWAY, JUNCTION)]).unique()
    per_actor = tracks.unique().join(types, on=["drive_id", "actor_id"])
    assert per_actor.height == types.height  # every actor has one kind and size, the one of its vType
    got = set(per_actor.select("type_id", "kind", "length_m", "width_m").unique().rows())
    assert got == {("car", "vehicle", 4.6, 1.8), ("aggressive", "vehicle", 4.5, 1.8), ("truck", "truck", 16.5, 2.55),
                   ("bike", "cyclist", 1.6, 0.65)}
    bikes = per_actor.filter(pl.col("type_id") == "bike")
    assert bikes.height > 10 and set(bikes["drive_id"]) == {"junction_s1"}


# ---------------------------------------------------------------------------------------------------- map

def _map(db: Path, run: Path, table: str) -> pl.DataFrame:
    return _sql(db, f"select t.* from {table} t join drive_inputs d using (map_id) where d.drive_id = $d",
                d=run.name)


def test_lanes_are_the_network_lanes(db):
    for run in (MOTORWAY, JUNCTION):
        net_lanes = {lane.get("id"): lane for lane in _net(run).iter("lane")}
        lanes = {r["lane_id"]: r for r in _map(db, run, "lanes").to_dicts()}
        assert set(lanes) == set(net_lanes)
        for lid, lane in net_lanes.items():
            row = lanes[lid]
            assert row["lane_type"] == ("internal" if lid.startswith(":") else "normal")
            assert row["speed_limit_mps"] == float(lane.get("speed"))
            line = shapely.from_wkt(row["centerline_wkt"])
            shape = [tuple(map(float, p.split(","))) for p in lane.get("shape").split()]
            assert list(line.coords) == shape
            poly = shapely.from_wkt(row["polygon_wkt"])  # the centre line buffered by 3.2 m / 2, flat ends
            assert poly.is_valid and poly.area == pytest.approx(line.length * 3.2, rel=0.02)
            assert (row["junction_id"] is not None) == lid.startswith(":")
    lanes = {r["lane_id"]: r for r in _map(db, MOTORWAY, "lanes").to_dicts()}
    assert sum(not k.startswith(":") for k in lanes) == 3 + 4 + 3 + 4 + 3 + 1 + 1  # AB BC CD DE EF, two ramps
    assert (lanes["BC_1"]["left_lane_id"], lanes["BC_1"]["left_same_direction"]) == ("BC_2", True)
    assert (lanes["BC_1"]["right_lane_id"], lanes["BC_1"]["right_same_direction"]) == ("BC_0", True)
    assert lanes["BC_3"]["left_lane_id"] is None and lanes["BC_0"]["right_lane_id"] is None
    assert lanes[":D_0_1"]["junction_id"] == "D" and lanes[":D_0_1"]["right_lane_id"] == ":D_0_0"


def test_lane_successors_with_internal_lanes_and_turns(db):
    motorway = {(r["lane_id"], r["successor_id"]): r["turn"] for r in _map(db, MOTORWAY, "lane_successors").to_dicts()}
    assert not any(a == "BC_0" for a, _ in motorway)  # the acceleration lane ends: ramp traffic must merge
    assert motorway[("RB_0", ":B_3_0")] == "straight" and motorway[(":B_3_0", "BC_0")] == "straight"
    assert {b for a, b in motorway if a == "CD_0"} == {":D_0_0", ":D_0_1"}  # the deceleration lane opens
    assert motorway[("DE_0", ":E_0_0")] == "straight" and motorway[(":E_0_0", "EX_0")] == "straight"
    turn = {"s": "straight", "l": "left", "r": "right", "L": "left", "R": "right"}
    for run in (MOTORWAY, JUNCTION):
        found = {(r["lane_id"], r["successor_id"]): r["turn"] for r in _map(db, run, "lane_successors").to_dicts()}
        connections = list(_net(run).iter("connection"))
        assert len(found) == len(connections)  # one successor per connection, none invented
        for c in connections:
            src, dst = f"{c.get('from')}_{c.get('fromLane')}", c.get("via") or f"{c.get('to')}_{c.get('toLane')}"
            assert found[(src, dst)] == turn[c.get("dir")]
    junction = {(r["lane_id"], r["successor_id"]): r["turn"] for r in _map(db, JUNCTION, "lane_successors").to_dicts()}
    # the permissive left turn waits at an internal junction: two internal lanes
    assert junction[("N2C_2", ":C_3_0")] == "left"
    assert junction[(":C_3_0", ":C_16_0")] == "left" and junction[(":C_16_0", "C2E_1")] == "left"
    assert junction[("N2C_0", ":C_0_0")] == "right" and junction[("N2C_0", ":C_1_0")] == "straight"
    assert _map(db, JUNCTION, "junctions")["junction_id"].to_list() == ["C"]
    assert sorted(_map(db, MOTORWAY, "junctions")["junction_id"]) == ["B", "C", "D", "E"]


def test_traffic_lights_per_controlled_link(db):
    lights = _map(db, JUNCTION, "traffic_lights")
    assert lights["light_id"].n_unique() == 16
    c3 = lights.filter(pl.col("light_id") == "C:3").sort("lane_id")
    assert c3["lane_id"].to_list() == [":C_3_0", "N2C_2"]  # the approach lane and the internal lane it opens
    n2c_2 = shapely.from_wkt(_map(db, JUNCTION, "lanes").filter(pl.col("lane_id") == "N2C_2")["centerline_wkt"][0])
    assert (c3["x_m"][0], c3["y_m"][0]) == pytest.approx(n2c_2.coords[-1])  # stop line = end of the approach
    assert set(lights.filter(pl.col("lane_id") == "N2C_0")["light_id"]) == {"C:0", "C:1"}  # right and straight
    assert _map(db, MOTORWAY, "traffic_lights").is_empty()


def test_traffic_light_states_follow_the_raw_records(db):
    states = _sql(db, "select light_id, frame, state from traffic_light_states where drive_id = 'junction_s1'")
    raw = [(round(float(e.get("time")) * 10), e.get("state"))
           for e in ET.fromstring(gzip.decompress((JUNCTION / "tls_states.xml.gz").read_bytes())).iter("tlsState")]
    colour = {"G": "green", "g": "green", "y": "yellow", "r": "red"}
    expected = {(f"C:{i}", frame): colour[c] for frame, s in raw for i, c in enumerate(s)}
    got = {(r[0], r[1]): r[2] for r in states.rows()}
    max_frame = _sql(db, "select max(frame) as m from tracks where drive_id = 'junction_s1'")["m"][0]
    assert len(got) == 16 * (max_frame + 1)
    assert {k: v for k, v in got.items() if k in expected} == expected
    # frame 0: GGGgrrrrGGGgrrrr: link 3 (the left turn from the north) is a permissive g: green
    assert raw[0] == (0, "GGGgrrrrGGGgrrrr")
    assert got[("C:3", 0)] == "green" and got[("C:4", 0)] == "red"
    assert got[("C:0", 430)] == "yellow"  # phase 1 (yyyy...) starts at 42 s


# -------------------------------------------------------------------------------------------- localisation

@pytest.mark.parametrize("run", [MOTORWAY, JUNCTION], ids=lambda r: r.name)
def test_lanes_from_x_y_agree_with_sumo(db, run):
    """The lane localisation finds from x/y alone (the in-lane rule of actor_lanes.sql) is SUMO's lane.

    SUMO's lane is the lane of the front bumper; the box centre is half a length behind it, so the two differ
    legitimately where the centre is still on the previous lane (lane_pos_m < length / 2), mostly on entering
    and leaving junctions.
    """
    best = _sql(db, """
        select actor_id, frame, lane_id as found from (
            select *, row_number() over (partition by actor_id, frame order by dist_m, abs(heading_diff_rad), lane_id)
                as r
            from track_lanes where drive_id = $d and dist_m <= 1 and abs(heading_diff_rad) < pi() / 2)
        where r = 1""", d=run.name)
    sizes = read_vtypes(run).select("type_id", "length_m")
    rows = _fcd(run).join(sizes, on="type_id").join(best, on=["actor_id", "frame"], how="left")
    agree = (pl.col("found") == pl.col("lane_id")).fill_null(False)
    away = ~pl.col("lane_id").str.starts_with(":") & (pl.col("lane_pos_m") >= pl.col("length_m") / 2)
    all_rate = rows.select(agree.mean()).item()
    away_rate = rows.filter(away).select(agree.mean()).item()
    assert rows.filter(away).height > 0.9 * rows.height
    assert away_rate >= 0.999, away_rate  # measured 1.0 (motorway) and 0.99996 (junction)
    assert all_rate >= 0.97, all_rate  # measured 0.994 and 0.988


# ---------------------------------------------------------------------------------------------------- errors

def _runs(tmp_path: Path) -> Path:
    runs = tmp_path / "runs"
    shutil.copytree(JUNCTION, runs / "good")
    return runs


def test_a_folder_without_a_network_is_rejected_and_the_others_ingest(tmp_path):
    runs = _runs(tmp_path)
    shutil.copytree(MOTORWAY, runs / "nonet", ignore=shutil.ignore_patterns("*.net.xml.gz"))
    with pytest.raises(InputError, match=r"nonet: no SUMO network file \(none named by a \.sumocfg"):
        list(read_sumo(runs / "nonet"))
    db = tmp_path / "x.duckdb"
    summary = ingest("sumo", [runs], db)
    assert (summary.drives, summary.rejected) == (1, 1)
    drives = {r["drive_id"]: r for r in _sql(db, "select * from drive_inputs").iter_rows(named=True)}
    assert drives["good"]["status"] == "ingested"
    assert drives["nonet"]["status"] == "rejected" and "no SUMO network file" in drives["nonet"]["reject_reason"]
    assert str(runs / "nonet") in drives["nonet"]["reject_reason"]


def test_a_truncated_gzip_fcd_is_rejected_and_the_others_ingest(tmp_path):
    runs = _runs(tmp_path)
    shutil.copytree(MOTORWAY, runs / "cut")
    fcd = runs / "cut" / "fcd.xml.gz"
    fcd.write_bytes(fcd.read_bytes()[: fcd.stat().st_size // 2])
    with pytest.raises(InputError) as err:
        list(read_sumo(runs / "cut"))
    assert str(err.value) == (
        f"{fcd}: cannot be read to the end (Compressed file ended before the end-of-stream marker was reached); "
        "the file is truncated or corrupt. Fix: copy or regenerate it (SUMO must finish writing it).")
    db = tmp_path / "x.duckdb"
    assert (ingest("sumo", [runs], db).drives, 1) == (1, 1)
    drives = {r["drive_id"]: r for r in _sql(db, "select * from drive_inputs").iter_rows(named=True)}
    assert drives["cut"]["status"] == "rejected" and str(fcd) in drives["cut"]["reject_reason"]
    assert drives["good"]["status"] == "ingested" and drives["good"]["rows_read"] == zlib_count(JUNCTION)


def test_a_plain_fcd_cut_mid_way_is_an_input_error(tmp_path):
    run = tmp_path / "plain"
    shutil.copytree(JUNCTION, run, ignore=shutil.ignore_patterns("fcd.xml.gz"))
    text = gzip.decompress((JUNCTION / "fcd.xml.gz").read_bytes())
    (run / "fcd.xml").write_bytes(text[: len(text) // 2])  # cut inside a line, as a killed run leaves it
    with pytest.raises(InputError, match=r"fcd\.xml: ends before </fcd-export> .*the file is truncated"):
        list(read_sumo(run))


def test_unknown_vehicle_types_are_dropped_with_the_reason(tmp_path):
    run = tmp_path / "notypes"
    shutil.copytree(JUNCTION, run)
    routes = (run / "routes.rou.xml").read_text()
    (run / "routes.rou.xml").write_text(re.sub(r'<vType id="bike"[^>]*/>', "", routes))
    (drive,) = read_sumo(run)
    bikes = _fcd(JUNCTION).filter(pl.col("type_id") == "bike").height
    assert drive.rows_rejected == bikes > 0 and drive.tracks.height == drive.rows_read - bikes
    assert drive.reject_reason.startswith(f"{bikes} FCD row(s) of vehicle type(s) no route file defines dropped "
                                          "(bike)")


def test_two_fcd_files_in_one_folder_are_an_input_error(tmp_path):
    run = tmp_path / "two"
    shutil.copytree(JUNCTION, run)
    shutil.copy(run / "fcd.xml.gz", run / "fcd_copy.xml.gz")
    with pytest.raises(InputError, match=r"2 FCD files \(fcd.xml.gz, fcd_copy.xml.gz\); a run folder holds one"):
        list(read_sumo(run))


# ------------------------------------------------------------------------------------------------ simulate

def test_simulate_without_sumo_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "sumo", None)  # import sumo now raises ImportError
    from logiq_sql.evaluation.simulate import simulate

    with pytest.raises(LogiqError, match=re.escape("pip install 'logiq-sql[sumo]'")):
        simulate("junction", 1, 7, tmp_path / "x")


def test_simulate_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "usage: logiq-sql simulate" in out and "{motorway,junction}" in out and "[sumo]" in out


@pytest.mark.sumo
def test_simulate_and_ingest(tmp_path):
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    for kind in ("junction", "motorway"):
        assert main(["simulate", kind, "--minutes", "1", "--seed", "7", "--out", str(tmp_path / kind)]) == 0
        for name in ("network.net.xml.gz", "routes.rou.xml", "fcd.xml.gz", "lanechange.xml.gz", "ssm.xml.gz",
                     "tripinfo.xml.gz", "collisions.xml.gz", "cmd.txt", "SOURCE.md"):
            path = tmp_path / kind / name
            assert path.is_file(), name
            if name.endswith(".gz"):
                assert path.read_bytes()[:2] == b"\x1f\x8b", name  # SUMO really writes gzip
        cmd = (tmp_path / kind / "cmd.txt").read_text()
        assert "--seed 7" in cmd and "Eclipse SUMO sumo 1.28.0" in cmd
    assert (tmp_path / "junction" / "tls_states.xml.gz").read_bytes()[:2] == b"\x1f\x8b"
    # the same seed gives the same trajectories (SUMO's header comment holds the date)
    assert main(["simulate", "junction", "--minutes", "1", "--seed", "7", "--out", str(tmp_path / "again")]) == 0
    body = [re.sub(rb"<!--.*?-->", b"", gzip.decompress((tmp_path / d / "fcd.xml.gz").read_bytes()), flags=re.DOTALL)
            for d in ("junction", "again")]
    assert body[0] == body[1]
    db = tmp_path / "sim.duckdb"
    assert main(["ingest", "sumo", str(tmp_path / "junction"), str(tmp_path / "motorway"), "--db", str(db),
                 "--quiet"]) == 0
    drives = _sql(db, "select drive_id, status, rows_read from drive_inputs order by drive_id")
    assert drives.select("drive_id", "status").rows() == [("junction", "ingested"), ("motorway", "ingested")]
    assert drives["rows_read"].to_list() == [zlib_count(tmp_path / "junction"), zlib_count(tmp_path / "motorway")]
    frames = _sql(db, "select max(frame) + 1 as n from tracks where drive_id = 'junction'")["n"][0]
    states = _sql(db, "select count(*) as n from traffic_light_states where drive_id = 'junction'")["n"][0]
    assert states == 16 * frames  # every link at every frame


# ------------------------------------------------------------------------------------------ other FCD forms

def test_native_parquet_fcd_reads_like_the_xml(tmp_path):
    """SUMO 1.28's own Parquet FCD (``--fcd-output fcd.parquet``): columns timestep_time, vehicle_id, vehicle_x,
    ... (Float32 for angle, speed, pos, acceleration), no leader columns (they abort SUMO's Parquet writer)."""
    run = tmp_path / "parquet_run"
    shutil.copytree(JUNCTION, run, ignore=shutil.ignore_patterns("fcd.xml.gz"))
    xml = read_fcd(JUNCTION / "fcd.xml.gz")
    xml.select(
        timestep_time="t_s", vehicle_id="vehicle_id", vehicle_x="x_m", vehicle_y="y_m",
        vehicle_angle=pl.col("angle_deg").cast(pl.Float32), vehicle_type="type_id",
        vehicle_speed=pl.col("speed_mps").cast(pl.Float32), vehicle_pos=pl.col("lane_pos_m").cast(pl.Float32),
        vehicle_lane="lane_id", vehicle_acceleration=pl.col("accel_mps2").cast(pl.Float32),
    ).write_parquet(run / "fcd.parquet")
    got = read_fcd(run / "fcd.parquet")
    assert got.columns == xml.columns and got["leader_id"].null_count() == got.height
    assert got.select("t_s", "vehicle_id", "x_m", "y_m").equals(xml.select("t_s", "vehicle_id", "x_m", "y_m"))
    assert (got["angle_deg"] - xml["angle_deg"]).abs().max() < 1e-4  # Float32 in SUMO's Parquet
    ((a,), (b,)) = list(read_sumo(JUNCTION)), list(read_sumo(run))
    assert a.tracks.select("actor_id", "frame", "kind").equals(b.tracks.select("actor_id", "frame", "kind"))
    assert (a.tracks["x_m"] - b.tracks["x_m"]).abs().max() < 1e-4


def test_plain_xml_with_a_person(tmp_path):
    """A plain ``fcd.xml`` with a ``<person>`` (as SUMO 1.28 writes one: no lane, no acceleration)."""
    run = tmp_path / "walk"
    shutil.copytree(JUNCTION, run, ignore=shutil.ignore_patterns("fcd.xml.gz", "tls_states.xml.gz"))
    steps = "".join(
        f'    <timestep time="{t:.2f}">\n'
        f'        <vehicle id="v" x="292.00" y="{595.3 - 14 * t:.2f}" angle="180.00" type="car" speed="14.00" '
        f'pos="{4.7 + 14 * t:.2f}" lane="N2C_0" acceleration="0.00" leaderID="" leaderSpeed="-1" leaderGap="-1"/>\n'
        f'        <person id="p0" x="290.72" y="{574.08 - 1.3 * t:.2f}" angle="180.00" type="DEFAULT_PEDTYPE" '
        f'speed="1.30" pos="{25.92 + 1.3 * t:.2f}"/>\n'
        "    </timestep>\n" for t in (0.0, 0.1, 0.2))
    (run / "fcd.xml").write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<fcd-export>\n{steps}</fcd-export>\n')
    (drive,) = read_sumo(run)
    t = drive.tracks.sort("actor_id", "frame")
    assert t["actor_id"].to_list() == ["p0"] * 3 + ["v"] * 3 and t["frame"].to_list() == [0, 1, 2] * 2
    assert t["kind"].to_list() == ["person"] * 3 + ["vehicle"] * 3
    person = t.row(0, named=True)
    assert (person["length_m"], person["width_m"], person["accel_mps2"]) == (0.215, 0.478, None)
    assert person["y_m"] == pytest.approx(574.08 + 0.215 / 2)  # heading south: the centre is north of the front
    assert t.filter(pl.col("actor_id") == "v")["y_m"].to_list() == pytest.approx([597.6, 596.2, 594.8])
    assert drive.traffic_light_states.is_empty() and drive.dt_s == 0.1


# ------------------------------------------------------------------------------- regimes and perceived copies

def test_regime_options_are_checked():
    from logiq_sql.evaluation.simulate import Regime

    with pytest.raises(LogiqError, match="--approach-lanes 5: choose one of 2, 3, 4"):
        Regime(approach_lanes=5)
    with pytest.raises(LogiqError, match="--truck-share 0.6, --bus-share 0.5 and --motorcycle-share 0: give shares"):
        Regime(truck_share=0.6, bus_share=0.5)
    with pytest.raises(LogiqError, match="--skew 50: give degrees in"):
        Regime(skew_deg=50)
    with pytest.raises(LogiqError, match="--cycle 20: give a signal cycle"):
        Regime(cycle_s=20)
    with pytest.raises(LogiqError, match="--speed 100: give the junction's speed limit"):
        Regime(speed_kmh=100)
    with pytest.raises(LogiqError, match="--lane-change-duration -1"):
        Regime(lane_change_duration_s=-1)


def test_perturbation_is_seeded_and_has_the_asked_spread():
    from logiq_sql.evaluation.perceive import Noise, perturb

    n = 20_000
    fcd = pl.DataFrame({"vehicle_id": [f"v{i % 50}" for i in range(n)], "x_m": [100.0] * n, "y_m": [5.0] * n,
                        "angle_deg": [359.9] * n, "speed_mps": [0.05] * n})
    noise = Noise(position_m=0.2, heading_deg=1.0, speed_mps=0.1, drop_share=0.02, seed=3)
    a, b = perturb(fcd, noise), perturb(fcd, noise)
    assert a.equals(b)  # same seed, same copy
    assert not a.equals(perturb(fcd, Noise(0.2, 1.0, 0.1, 0.02, seed=4)))
    assert abs(a.height / n - 0.98) < 0.005
    assert abs(a["x_m"].std() - 0.2) < 0.01 and abs(a["y_m"].std() - 0.2) < 0.01
    assert a["angle_deg"].is_between(0, 360, closed="left").all()  # wrapped, not 360.9
    assert (a["speed_mps"] >= 0).all() and (a["speed_mps"] == 0).any()  # clipped at 0
    assert perturb(fcd, Noise()).equals(fcd)
    with pytest.raises(InputError, match="drop_share = 1"):
        Noise(drop_share=1)


def test_perceived_copy_keeps_the_drive_id_and_leaves_the_run_alone(tmp_path):
    from logiq_sql.evaluation.perceive import Noise, perceive

    run = tmp_path / "runs" / "junction_s1"
    shutil.copytree(JUNCTION, run)
    before = {f.name: f.read_bytes() for f in run.iterdir()}
    copy = perceive(run, tmp_path / "perceived", Noise(position_m=0.2, drop_share=0.02, seed=1))
    assert copy == tmp_path / "perceived" / "junction_s1"
    assert {f.name: f.read_bytes() for f in run.iterdir()} == before
    assert not list(copy.glob("lanechange*")) and not list(copy.glob("ssm*"))  # no simulator answers
    with pytest.raises(InputError, match="would overwrite the run itself"):
        perceive(run, tmp_path / "runs", Noise())
    (drive,) = list(read_sumo(copy))
    (exact,) = list(read_sumo(run))
    assert drive.drive_id == exact.drive_id == "junction_s1"
    assert 0.97 * exact.tracks.height < drive.tracks.height < 0.99 * exact.tracks.height
    moved = drive.tracks.join(exact.tracks, on=["actor_id", "frame"], suffix="_exact").select(
        d=((pl.col("x_m") - pl.col("x_m_exact")) ** 2 + (pl.col("y_m") - pl.col("y_m_exact")) ** 2).sqrt())
    assert 0.2 < moved["d"].median() < 0.3  # a 2-D Gaussian of 0.2 m per axis: median 0.235 m


@pytest.mark.sumo
def test_simulated_regime_has_gradual_lane_changes_trucks_buses_and_a_perceived_copy(tmp_path):
    pytest.importorskip("sumo", reason="Eclipse SUMO is not installed: pip install 'logiq-sql[sumo]'")
    assert main(["simulate", "motorway", "--minutes", "1.5", "--seed", "7", "--out", str(tmp_path / "mw"),
                 "--perceived", str(tmp_path / "perceived"), "--noise-position", "0.2", "--noise-drop", "0.02"]) == 0
    assert "--lanechange.duration 3" in (tmp_path / "mw" / "cmd.txt").read_text()
    fcd = read_fcd(tmp_path / "mw" / "fcd.xml.gz", ("vehicle_id", "type_id", "y_m", "lane_id"))
    assert {"truck", "bus"} <= set(fcd["type_id"])
    changes = xml_records(tmp_path / "mw" / "lanechange.xml.gz", "change", ("id", "time", "from", "to"),
                          "</lanechanges>")
    assert changes.height > 20
    # a lane change is a sideways move over about 3 s (SUMO records it when the lane switches, half-way): no
    # jump of a lane width between two steps, but about a lane width over +-1.5 s
    f = fcd.with_columns(frame=(pl.col("t_s") * 10).round().cast(pl.Int64))
    c = changes.with_columns(frame=(pl.col("time").cast(pl.Float64) * 10).round().cast(pl.Int64)).filter(
        pl.col("from").str.starts_with("CD") & pl.col("to").str.starts_with("CD"))

    def y_at(offset: int) -> pl.DataFrame:
        return c.join(f.select("vehicle_id", "frame", y=pl.col("y_m")), left_on=["id", pl.col("frame") + offset],
                      right_on=["vehicle_id", "frame"]).select("id", "frame", pl.col("y").alias(f"y{offset}"))

    y = y_at(0).join(y_at(-1), on=["id", "frame"]).join(y_at(-15), on=["id", "frame"]).join(y_at(15), on=["id", "frame"])
    assert y.height > 5
    assert ((y["y0"] - y["y-1"]).abs() < 0.3).all()
    assert ((y["y15"] - y["y-15"]).abs() > 2.0).all()
    assert (tmp_path / "perceived" / "mw" / "fcd.parquet").is_file()


def test_noise_without_a_perceived_copy_is_refused(capsys):
    assert main(["simulate", "motorway", "--out", "never_written", "--noise-drop", "0.02"]) == 2
    assert "add --perceived DIR" in capsys.readouterr().err
    assert not Path("never_written").exists()


def test_a_runs_command_line_parses_back_into_its_regime():
    """cmd.txt spells the regime as `logiq-sql eval simulate` options: each must exist and give the same regime."""
    import shlex

    from logiq_sql.cli import build_parser
    from logiq_sql.evaluation.simulate import Regime, command_options

    regime = Regime(motorcycle_share=0.1, skew_deg=15, cycle_s=60, speed_kmh=40, exit_backup=True, approach_lanes=2)
    args = build_parser().parse_args(["eval", "simulate", *shlex.split(command_options("junction", 5, 7, regime)),
                                      "--out", "run"])
    assert (args.motorcycle_share, args.skew, args.cycle, args.speed, args.exit_backup, args.approach_lanes) == (
        0.1, 15, 60, 40, True, 2)
