"""The replay and the report read at a glance (issue 37): axes carry units, texts never overprint, the ego and the
actor stay in view for every frame of the match, the tested headway and its bridged frames are shown, a scenario
without a match takes one line. Checked on the GIF's figure (matplotlib text extents) and on the report and its
replays in headless Chromium (SVG text boxes, the canvas's text boxes as replay.js measures them). Screenshots go
to $LOGIQ_SQL_SCREENSHOT_DIR when set (CI keeps them), else to the test's tmp dir."""

from __future__ import annotations

import itertools
import os
import shutil
from pathlib import Path

import duckdb
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Text

from logiq_sql.cli import main
from logiq_sql.outputs import replay
from logiq_sql.storage.db import connect
from tests.outputs.test_analysts import CHROMIUM, CHROMIUM_ARGS, REPLAYS, _chromium

# a box may touch its neighbour by this much (pixels): antialiasing and font metrics, not overprint
TOUCH_PX = 1.0


@pytest.fixture(scope="module")
def db(tmp_path_factory, matched_drives):
    db = tmp_path_factory.mktemp("pictures") / "drives.duckdb"
    shutil.copyfile(matched_drives, db)
    return db


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    out = Path(os.environ.get("LOGIQ_SQL_SCREENSHOT_DIR") or tmp_path_factory.mktemp("shots"))
    out.mkdir(parents=True, exist_ok=True)
    return out


def picks(db) -> list[str]:
    """The match of each REPLAYS entry (first by start on its drive)."""
    with connect(db, read_only=True) as con:
        return [con.execute("select match_id from matches where scenario = $s and drive_id like $d "
                            "order by start_s, match_id limit 1", {"s": s, "d": f"%{d}%"}).fetchone()[0]
                for s, d in REPLAYS]


def special_picks(db) -> dict[str, str]:
    """A match with bridged frames and one whose actor's track ends before the replay does (first by match_id)."""
    with connect(db, read_only=True) as con:
        ids = [r[0] for r in con.execute("select match_id from matches order by match_id").fetchall()]
        scenes, _ = replay.scenes(con, ids)
    bridged = next(s["id"] for s in scenes if s["b"])
    ends = next(s["id"] for s in scenes if s["a"]["x"][-1] is None and any(v is not None for v in s["a"]["x"]))
    return {"bridged": bridged, "actor_ends": ends}


def overlaps(boxes: list[tuple[str, float, float, float, float]]) -> list[tuple[str, str]]:
    """Pairs of (text, x, y, w, h) boxes that overlap by more than TOUCH_PX both ways."""
    out = []
    for (a, ax, ay, aw, ah), (b, bx, by, bw, bh) in itertools.combinations(boxes, 2):
        if min(ax + aw, bx + bw) - max(ax, bx) > TOUCH_PX and min(ay + ah, by + bh) - max(ay, by) > TOUCH_PX:
            out.append((a, b))
    return out


def figure_texts(fig) -> list[tuple[str, float, float, float, float]]:
    """The (text, x, y, w, h) boxes of every text the figure draws (tick labels outside the view are not drawn)."""
    renderer = fig.canvas.get_renderer()
    axes = [a for a in fig.axes if a.get_visible()]
    drawn = {id(t) for a in axes for axis in (a.xaxis, a.yaxis) for tick in axis._update_ticks()
             for t in (tick.label1, tick.label2)}
    ticks = {id(t) for a in fig.axes for axis in (a.xaxis, a.yaxis)
             for tick in axis.get_major_ticks() + axis.get_minor_ticks() for t in (tick.label1, tick.label2)}
    out = []
    for t in fig.findobj(Text):
        if not (t.get_visible() and t.get_text().strip()) or (t.axes is not None and not t.axes.get_visible()):
            continue
        if id(t) in ticks and id(t) not in drawn:
            continue
        e = t.get_window_extent(renderer)
        out.append((t.get_text(), e.x0, e.y0, e.width, e.height))
    return out


def test_the_replay_figure_reads_at_a_glance(db, shots):
    """The GIF's figure at every frame of each match: both boxes inside the map's view, no two texts overlap and
    all lie inside the figure, every axis names its unit; the headway shown is the one the phase tests."""
    for (scenario, drive), match_id in zip(REPLAYS, picks(db), strict=True):
        s = replay.scene(db, match_id)
        anim = replay.animation(s)
        fig, ax, draw = anim.parts["figure"], anim.parts["map"], anim.parts["draw"]
        FigureCanvasAgg(fig)
        d = replay.decode(s)
        inside = np.flatnonzero((d["t_s"] >= s["start_s"] - 1e-6) & (d["t_s"] <= s["end_s"] + 1e-6))
        for i in inside:
            draw(i)
            (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
            for who in ("ego", "actor"):
                box = anim.parts["boxes"][who]
                if box.get_visible():
                    xy = box.get_xy()
                    assert (xy[:, 0] >= x0).all() and (xy[:, 0] <= x1).all(), (match_id, who, i)
                    assert (xy[:, 1] >= y0).all() and (xy[:, 1] <= y1).all(), (match_id, who, i)
        for i in (inside[0], inside[len(inside) // 2], len(d["t_s"]) - 1):
            draw(i)
            fig.canvas.draw()
            texts = figure_texts(fig)
            assert overlaps(texts) == [], (scenario, drive, i)
            width, height = fig.canvas.get_width_height()
            assert all(x >= 0 and y >= 0 and x + w <= width + 0.5 and y + h <= height + 0.5
                       for _, x, y, w, h in texts), (scenario, drive)
        fig.savefig(shots / f"gif_{scenario}_{drive}.png")
        labels = [a.get_xlabel() for a in fig.axes] + [a.get_ylabel() for a in fig.axes]
        assert {"x (m)", "y (m)", replay.TIME_LABEL, "gap (m)", "headway, TTC (s)", "speed (mph)"} <= set(labels)
        assert all("(" in label for label in labels if label)
        assert "ego ego" not in " ".join(replay.titles(s))
        expected = "follow_headway_s" if scenario == "follower_vehicle" else "time_headway_s"
        assert s["hw"]["column"] == expected


def test_every_match_keeps_both_boxes_in_view(db):
    """Over every bundled match (each scenario, NGSIM, nuScenes, the SUMO junction): at every frame of the match the
    ego's and the actor's box corners are inside the view the renderers draw (view_centres, view_m, the map's
    aspect)."""
    with connect(db, read_only=True) as con:
        ids = [r[0] for r in con.execute("select match_id from matches order by match_id").fetchall()]
        scenes, _ = replay.scenes(con, ids)
    map_w, map_h = (replay.LAYOUT["map"][2] * replay.LAYOUT["width"], replay.LAYOUT["map"][3] * replay.LAYOUT["height"])
    checked = 0
    for s in scenes:
        d = replay.decode(s)
        centres, half_w = replay.view_centres(d), s["view_m"]
        half_h = half_w * map_h / map_w
        for i in np.flatnonzero((d["t_s"] >= s["start_s"] - 1e-6) & (d["t_s"] <= s["end_s"] + 1e-6)):
            for a in (d["ego"], d["actor"]):
                if np.isnan(a["x"][i]):
                    continue
                xy = replay.box_corners(a["x"][i], a["y"][i], a["h"][i], a["l"], a["w"]) - centres[i]
                assert (np.abs(xy[:, 0]) <= half_w).all() and (np.abs(xy[:, 1]) <= half_h).all(), (s["id"], i)
                checked += 1
    assert len(scenes) == len(ids) and checked > 10_000


def test_the_follower_headway_is_the_one_the_phase_tests(db):
    """The headway panel of a follower match is follow_gap_m / actor speed (phases/follower_vehicle.sql), read
    here from the kept relations and tracks, and inside the follower phase every frame either holds the tested
    range or is marked bridged."""
    with connect(db, read_only=True) as con:
        ids = [r[0] for r in con.execute("select match_id from matches where scenario = 'follower_vehicle' "
                                         "order by match_id").fetchall()]
        scenes, _ = replay.scenes(con, ids)
        for s in scenes[::9]:
            d = replay.decode(s)
            want = con.execute(
                "select greatest(r.lon_gap_m + r.lat_gap_m, r.box_distance_m) / a.speed_mps from relations r "
                "join tracks a on r.drive_id = a.drive_id and r.actor_id = a.actor_id and r.frame = a.frame "
                "where r.drive_id = $d and r.ego_id = $e and r.actor_id = $a and a.speed_mps > 0 "
                "and r.t_s between $from and $to order by r.frame",
                {"d": s["drive"], "e": s["ego"], "a": s["actor"], "from": s["start_s"] - 1e-6,
                 "to": s["end_s"] + 1e-6}).fetchnumpy()
            inside = (d["t_s"] >= s["start_s"] - 1e-6) & (d["t_s"] <= s["end_s"] + 1e-6)
            shown = d["series"]["headway_s"][inside]
            shown = shown[np.isfinite(shown)]
            got = next(iter(want.values()))
            assert len(shown) == len(got) and np.abs(shown - got).max() <= 0.05 + 1e-9, s["id"]
    bridged = 0
    for s in scenes:
        d = replay.decode(s)
        hw, lo, hi = d["series"]["headway_s"], s["hw"]["lo"], s["hw"]["hi"]
        inside = np.flatnonzero((d["t_s"] >= s["start_s"] - 1e-6) & (d["t_s"] <= s["end_s"] + 1e-6))
        out = [i for i in inside if not (lo <= hw[i] <= hi)]  # NaN (undefined) is out too
        assert set(out) <= set(d["bridged"].tolist()), s["id"]
        bridged += len(d["bridged"])
    assert bridged > 0  # the bundled followers have bridged frames, and they are marked


def _svg_texts(page, k: int) -> list[tuple[str, float, float, float, float]]:
    return page.evaluate(
        """k => Array.from(document.querySelectorAll('.chart svg')[k].querySelectorAll('text'))
               .filter(t => t.textContent.trim()).map(t => { const b = t.getBoundingClientRect();
               return [t.textContent, b.x, b.y, b.width, b.height]; })""", k)


def test_the_report_and_its_replays_read_at_a_glance_in_chromium(db, shots, tmp_path):
    sync_playwright = _chromium()
    html = tmp_path / "report.html"
    assert main(["report", "--db", str(db), "--out", str(html)]) == 0
    errors = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 1000})
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(html.as_uri())
        page.wait_for_load_state("load")
        charts = page.locator(".chart svg").count()
        assert charts > 0
        for k in range(charts):
            texts = _svg_texts(page, k)
            assert overlaps(texts) == [], (k, overlaps(texts)[:3])
        coverage = " ".join(t for k in range(charts) for t, *_ in _svg_texts(page, k))
        assert "value (mph)" in coverage and "[0, 10) mph" in coverage and "value (kph)" in coverage
        page.locator(".chart").first.screenshot(path=str(shots / "report_coverage.png"))
        page.locator("h2", has_text="KPI distributions").scroll_into_view_if_needed()
        page.screenshot(path=str(shots / "report_kpis.png"))
        special = special_picks(db)
        cases = [*zip(REPLAYS, picks(db), strict=True), *(((why, ""), m) for why, m in special.items())]
        for (scenario, drive), match_id in cases:
            k = page.evaluate(f"Array.from(document.querySelectorAll('#matches tbody tr')).findIndex("
                              f"r => r.textContent.includes('{match_id}'))")
            page.locator("#matches tbody tr").nth(k).locator("button[data-replay]").click()
            page.wait_for_function("document.getElementById('replay').dataset.ready")
            canvas = page.evaluate("[document.getElementById('replay-canvas').width, "
                                   "document.getElementById('replay-canvas').height]")
            n = page.evaluate("window.logiqReplay.state.n")
            states = page.evaluate(f"""() => {{ const out = [];
                for (let i = 0; i < {n}; i++) {{ window.logiqReplay.show(i); out.push(window.logiqReplay.state); }}
                return out; }}""")
            assert any(st["inMatch"] for st in states)
            for st in states:
                if st["inMatch"]:
                    x, y, w, h = st["view"]
                    for who in ("egoBox", "actorBox"):
                        for px, py in st[who] or []:
                            assert x <= px <= x + w and y <= py <= y + h, (match_id, who, st["frame"])
                texts = [(t["text"], t["x"], t["y"], t["w"], t["h"]) for t in st["texts"]]
                assert overlaps(texts) == [], (match_id, st["frame"], overlaps(texts)[:3])
                assert all(t[1] >= 0 and t[2] >= 0 and t[1] + t[3] <= canvas[0] and t[2] + t[4] <= canvas[1]
                           for t in texts), (match_id, st["frame"])
            words = {t["text"] for st in states for t in st["texts"]}
            assert {"x (m)", "y (m)", replay.TIME_LABEL, "gap (m)", "headway, TTC (s)", "speed (mph)"} <= words
            assert not any(w.endswith("n/a") for w in words)
            if match_id == special["bridged"]:
                assert "bridged frame" in words
            if match_id == special["actor_ends"]:
                assert any(w.startswith("actor track ends at t=") for w in words)
            assert "ego ego" not in page.text_content("#replay-title")
            at = n - 1 if match_id == special["actor_ends"] else int(n * 0.6)
            page.evaluate(f"window.logiqReplay.show({at})")
            page.locator("#replay").screenshot(path=str(shots / f"report_replay_{scenario}_{drive}.png"))
            page.click("#replay-close")
        browser.close()
    assert errors == []


def test_a_scenario_without_a_match_takes_one_line(db, tmp_path):
    empty = tmp_path / "empty.duckdb"
    shutil.copyfile(db, empty)
    with duckdb.connect(str(empty)) as con:
        con.execute("delete from matches where scenario = 'cyclist_close_to_moving_sut'")
    html = tmp_path / "report.html"
    assert main(["report", "--db", str(empty), "--out", str(html)]) == 0
    text = html.read_text()
    assert text.count("cyclist_close_to_moving_sut: no match in this file") == 2  # coverage and KPIs
    assert "coverage of cyclist_close_to_moving_sut" not in text
