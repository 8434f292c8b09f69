"""Match replays (logiq_sql/outputs/replay.py): the scene holds the tracks, the relation values and the phases of the match,
the CLI writes GIF and MP4, the notebook function animates, and a report scene stays small. The replay playing in
headless Chromium is in test_analysts.py, beside the report test."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from matplotlib.animation import FuncAnimation
from PIL import Image

from logiq_sql.cli import main
from logiq_sql.outputs import replay
from logiq_sql.storage.db import connect

SCENARIOS = ("follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut",
             "unprotected_left_turn_with_yield_and_traffic_light")


@pytest.fixture(scope="module")
def db(tmp_path_factory, matched_drives):
    db = tmp_path_factory.mktemp("replay") / "drives.duckdb"
    shutil.copyfile(matched_drives, db)  # tests.outputs.test_analysts.build_matched_db's file, built once per session
    return db


@pytest.fixture(scope="module")
def all_scenes(db):
    with connect(db, read_only=True) as con:
        ids = [r[0] for r in con.execute("select match_id from matches order by match_id").fetchall()]
        return replay.scenes(con, ids)


def first_match(db, scenario: str) -> str:
    with connect(db, read_only=True) as con:
        return con.execute("select min(match_id) from matches where scenario = $s", {"s": scenario}).fetchone()[0]


def test_every_match_has_a_scene_and_its_map(db, all_scenes):
    scenes, maps = all_scenes
    with connect(db, read_only=True) as con:
        expected = con.execute("select match_id, map_id from matches join drive_inputs using (drive_id) "
                               "order by match_id").fetchall()
    assert [(s["id"], s["map"]) for s in scenes] == expected
    assert set(maps) == {m for _, m in expected}
    assert all(maps[m]["lanes"] for m in maps)  # every bundled map has lanes in view


def test_positions_and_headings_are_the_tracks_to_the_quantum(db, all_scenes):
    scenes, _ = all_scenes
    with connect(db, read_only=True) as con:
        for s in scenes[::7]:
            d = replay.decode(s)
            track = con.execute("select t_s, x_m, y_m, heading_rad from tracks where drive_id = $d and actor_id = $e "
                                "and t_s between $a and $b order by frame",
                                {"d": s["drive"], "e": s["ego"], "a": d["t_s"][0] - 1e-6,
                                 "b": d["t_s"][-1] + 1e-6}).fetchnumpy()
            assert np.allclose(track["t_s"], d["t_s"], atol=1e-6)
            assert np.abs(track["x_m"] - d["ego"]["x"]).max() <= replay.QUANTUM_M / 2 + 1e-9
            assert np.abs(track["y_m"] - d["ego"]["y"]).max() <= replay.QUANTUM_M / 2 + 1e-9
            assert np.abs(track["heading_rad"] - d["ego"]["h"]).max() <= 0.005 + 1e-9


def test_the_gap_over_the_match_is_the_kpi_gap(db, all_scenes):
    """The per-frame gap comes from relations.sql, so its least value over the match is the KPI the matcher wrote
    (ego_min_distance_to_vehicle_m), to the quantum."""
    scenes, _ = all_scenes
    with connect(db, read_only=True) as con:
        kpi = dict(con.execute("select match_id, ego_min_distance_to_vehicle_m from kpis join matches "
                               "using (match_id, scenario) where ego_min_distance_to_vehicle_m is not null "
                               "and scenario in ('follower_vehicle', 'sut_cut_out')").fetchall())
    checked = 0
    for s in scenes:
        if s["id"] in kpi:
            d = replay.decode(s)
            inside = (d["t_s"] >= s["start_s"] - 1e-6) & (d["t_s"] <= s["end_s"] + 1e-6)
            assert abs(np.nanmin(d["series"]["lon_gap_m"][inside]) - kpi[s["id"]]) <= 0.05 + 1e-9, s["id"]
            checked += 1
    assert checked == len(kpi) > 200


def test_phases_pet_and_other_road_users(db, all_scenes):
    scenes, _ = all_scenes
    with connect(db, read_only=True) as con:
        phases = con.execute("select match_id, phase_index, phase, start_frame, end_frame from match_phases "
                             "order by match_id, phase_index").fetchall()
        pet = dict(con.execute("select match_id, pet_between_sut_and_npc_s from kpis").fetchall())
    by_id = {s["id"]: s for s in scenes}
    for match_id, index, name, start, end in phases:
        s = by_id[match_id]
        frames = np.cumsum(s["f"])
        shown = [p for p in s["p"] if p[0] == index][0]
        assert shown[1] == name and frames[shown[2]] == start and frames[shown[3]] == end
    left = [s for s in scenes if s["scenario"].startswith("unprotected_left_turn")]
    assert left and all(s["pet_s"] == pet[s["id"]] for s in left)
    assert any(s["pet_s"] is not None for s in left)
    # NGSIM is dense traffic: the faint other road users are there, and only within range of the ego
    cut_out = replay.decode(next(s for s in scenes if s["scenario"] == "sut_cut_out"))
    assert cut_out["others"]
    for o in cut_out["others"]:
        near = np.hypot(o["x"] - cut_out["ego"]["x"], o["y"] - cut_out["ego"]["y"])
        assert np.nanmax(near) <= replay.OTHERS_RANGE_M + replay.QUANTUM_M


def test_a_report_scene_is_small(all_scenes):
    """What the report embeds per match (gzip + base64), measured on every bundled match: kept under 6 kB."""
    scenes, maps = all_scenes
    sizes = np.array([len(replay.pack(s)) for s in scenes])
    assert sizes.mean() < 6000 and sizes.max() < 30_000, (sizes.mean(), sizes.max())
    assert sum(len(replay.pack(m)) for m in maps.values()) < 50_000


def test_cli_writes_a_gif_and_an_mp4(db, tmp_path, capsys):
    match_id = first_match(db, "sut_cut_out")
    n = len(replay.scene(db, match_id)["f"])
    gif, mp4 = tmp_path / "cut.gif", tmp_path / "cut.mp4"
    assert main(["replay", "--db", str(db), match_id, "--out", str(gif), "--step", "5"]) == 0
    assert str(gif) in capsys.readouterr().out
    with Image.open(gif) as im:
        assert im.size == (replay.LAYOUT["width"], replay.LAYOUT["height"])
        assert im.n_frames == len(range(0, n, 5))
        im.seek(0)
        first = np.asarray(im.convert("RGB"))
        im.seek(im.n_frames - 1)
        assert (np.asarray(im.convert("RGB")) != first).any()  # the picture moves
    assert main(["replay", "--db", str(db), match_id, "--out", str(mp4), "--step", "5"]) == 0
    assert mp4.read_bytes()[4:8] == b"ftyp" and mp4.stat().st_size > 10_000


def test_cli_replay_names_the_problem(db, tmp_path, capsys):
    assert main(["replay", "--db", str(db), "nope", "--out", str(tmp_path / "x.gif")]) == 2
    assert "match_id nope" in capsys.readouterr().err
    assert main(["replay", "--db", str(db), first_match(db, "follower_vehicle"), "--out",
                 str(tmp_path / "x.avi")]) == 2
    assert ".gif or an .mp4" in capsys.readouterr().err
    assert main(["replay", "--db", str(tmp_path / "missing.duckdb"), "m", "--out", str(tmp_path / "x.gif")]) == 2


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_animation_for_notebooks(db, scenario):
    s = replay.scene(db, first_match(db, scenario))
    anim = replay.animation(s, step=10)
    assert isinstance(anim, FuncAnimation)
    page = anim.to_jshtml()
    assert page.count("data:image/png;base64") == len(range(0, len(s["f"]), 10))
