"""For analysts and scheduled reports: the example queries of docs/queries.md, the query command, and the HTML
report opened in headless Chromium."""

from __future__ import annotations

import math
import os
import re
import shutil
import sys
from pathlib import Path

import duckdb
import pytest

from logiq_sql import InputError, ingest, match
from logiq_sql.cli import main
from logiq_sql.outputs.plots import birds_eye
from logiq_sql.storage import db

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests/data"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def build_matched_db(db: Path) -> Path:
    """The bundled drives that docs/queries.md describes: three NGSIM US-101 scenes, nuScenes scene-0103, and the
    SUMO junction with every third car as the SUT (it has every scenario, the left turn included)."""
    ngsim = DATA / "commonroad_ngsim/scenarios_2018b"
    ingest("commonroad", [ngsim / f"USA_US101-{n}_1_T-1.xml.gz" for n in (22, 24, 26)], db)
    ingest("scenarionet", [DATA / "nuscenes_mini_scenarionet/sd_nuscenes_v1.0-mini_scene-0103.pkl"], db)
    ingest("sumo", [DATA / "sumo/junction_s1"], db)
    with duckdb.connect(str(db), read_only=True) as con:
        recorded = [r[0] for r in con.execute("select drive_id from drive_inputs where source_format <> 'sumo'")
                    .fetchall()]
    match(db, drives=recorded, keep=True)  # keep: docs/queries.md also queries the kept relations
    match(db, drives=["junction_s1"], ego="every:3", keep=True)
    return db


@pytest.fixture(scope="module")
def matched_db(tmp_path_factory, matched_drives) -> Path:
    db = tmp_path_factory.mktemp("analysts") / "drives.duckdb"
    shutil.copyfile(matched_drives, db)  # build_matched_db's file, built once per session
    return db


def example_queries() -> list[tuple[str, str]]:
    """(heading, SQL) of every ```sql block of docs/queries.md."""
    text = (ROOT / "docs/queries.md").read_text()
    out = []
    for m in re.finditer(r"^```sql\n(.*?)^```", text, flags=re.DOTALL | re.MULTILINE):
        heading = re.findall(r"^## (.+)$", text[:m.start()], flags=re.MULTILINE)[-1]
        out.append((heading, m.group(1)))
    return out


def test_the_page_has_the_examples_the_issue_asks_for():
    headings = [h for h, _ in example_queries()]
    assert len(headings) == 8
    assert "Fast cut-outs with a short time to collision" in headings and "Coverage holes per scenario" in headings


@pytest.mark.parametrize("heading,sql", example_queries(), ids=[h for h, _ in example_queries()])
def test_every_example_query_returns_rows(matched_db, heading, sql):
    with duckdb.connect(str(matched_db), read_only=True) as con:
        rows = con.sql(sql).pl()
    assert rows.height > 0, heading


def test_fast_cut_outs_are_the_ones_measured(matched_db):
    (sql,) = [s for h, s in example_queries() if h.startswith("Fast cut-outs")]
    with duckdb.connect(str(matched_db), read_only=True) as con:
        rows = con.sql(sql).pl()
    # cut-outs of these scenes that qualify: ego 40 in US-101 scene 26, ego 44 in scene 24 and, since gradual lane
    # changes chain (the lane change dated where the ego crosses into the new lane), ego 675 in scene 22
    egos = sorted(rows.select("drive_id", "ego_id").rows())
    assert ("USA_US101-24_1_T-1@2018b", "44") in egos and ("USA_US101-26_1_T-1@2018b", "40") in egos
    assert ("USA_US101-22_1_T-1@2018b", "675") in egos and len(egos) == 3
    assert (rows["ego_max_speed_kph"] > 60).all() and (rows["min_ttc_s"] < 3).all()


def test_query_prints_a_table_and_cannot_write(matched_db, capsys):
    assert main(["query", "--db", str(matched_db),
                 "select scenario, count(*) as n from matches group by 1 order by 1"]) == 0
    out = capsys.readouterr().out
    assert "unprotected_left_turn_with_yield_and_traffic_light" in out and "│" in out
    assert main(["query", "--db", str(matched_db), "delete from matches"]) == 2
    assert "read-only" in capsys.readouterr().err
    with duckdb.connect(str(matched_db), read_only=True) as con:
        assert con.execute("select count(*) from matches").fetchone()[0] > 0
    assert main(["query", "--db", str(matched_db), "select nope from matches"]) == 2
    assert 'column "nope"' in capsys.readouterr().err.lower().replace("referenced column", "column")


def test_a_file_an_earlier_logiq_sql_wrote_is_refused_with_the_fix_until_a_run_upgrades_it(matched_db, tmp_path,
                                                                                           capsys):
    # read-only, the report, replays, exports and plots cannot add the columns added since (a binder error, before)
    old = tmp_path / "old.duckdb"
    shutil.copyfile(matched_db, old)
    with duckdb.connect(str(old)) as con:
        con.execute("alter table track_lanes drop column best_lane")  # as an earlier logiq_sql wrote it
        match_id = con.execute("select match_id from matches order by match_id limit 1").fetchone()[0]
    fix = r"no column track_lanes\.best_lane\. Fix: .*`logiq-sql match --db .*old\.duckdb`"
    for command in (["report", "--out", str(tmp_path / "r.html")],
                    ["replay", match_id, "--out", str(tmp_path / "r.gif")],
                    ["export", "xosc", match_id, "--out", str(tmp_path / "m.xosc")],
                    ["query", "select best_lane from track_lanes"]):
        assert main([*command, "--db", str(old)]) == 2, command
        assert re.search(fix, capsys.readouterr().err), command
    with pytest.raises(InputError, match=fix):
        birds_eye(old, match_id)
    # SQL that reads nothing added since still runs; a mistake of its own is given as DuckDB gives it
    assert main(["query", "--db", str(old), "select count(*) as n from matches"]) == 0
    assert main(["query", "--db", str(old), "select nope from matches"]) == 2
    err = capsys.readouterr().err
    assert 'column "nope"' in err.lower().replace("referenced column", "column") and re.search(fix, err)
    db.connect(old).close()  # what a run that writes the file does first
    assert main(["report", "--db", str(old), "--out", str(tmp_path / "r.html")]) == 0


def _chromium():
    if not Path(CHROMIUM).exists():
        message = (f"{CHROMIUM} is missing: apt-get install -y chromium (.ci/run installs it); the report test "
                   "needs it")
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    from playwright.sync_api import sync_playwright
    return sync_playwright


def test_report_renders_in_headless_chromium(matched_db, tmp_path):
    sync_playwright = _chromium()
    html = tmp_path / "report.html"
    screenshot = Path(os.environ.get("LOGIQ_SQL_SCREENSHOT_DIR") or tmp_path) / "report.png"  # kept by CI if set
    assert main(["report", "--db", str(matched_db), "--out", str(html)]) == 0
    text = html.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", text)  # nothing to fetch
    with duckdb.connect(str(matched_db), read_only=True) as con:
        total = con.execute("select count(*) from matches").fetchone()[0]
        left_turns = con.execute("select count(*) from matches where scenario like 'unprotected_left_turn%'"
                                 ).fetchone()[0]
    errors, requests = [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 1000})
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("request", lambda req: requests.append(req.url))
        page.goto(html.as_uri())
        page.wait_for_load_state("load")
        # a coverage grid and a KPI grid for every scenario found in scenarios/ (each matched here)
        from logiq_sql.spec.scenario import list_scenarios
        assert page.locator(".chart svg").count() == 2 * len(list_scenarios())
        assert page.locator(".chart svg").first.bounding_box()["width"] > 300
        rows = page.locator("#matches tbody tr:visible")
        assert rows.count() == total > left_turns > 0
        assert page.text_content("#match-count") == f"{total} of {total} matches"
        page.select_option("#scenario-filter", "unprotected_left_turn_with_yield_and_traffic_light")
        assert rows.count() == left_turns
        page.fill("#text-filter", "car_W_left.6")
        assert 0 < rows.count() < left_turns
        page.fill("#text-filter", "")
        page.select_option("#scenario-filter", "")
        assert rows.count() == total
        assert page.locator("#drives tbody tr").count() == 5
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(screenshot), full_page=False)  # the summary and first charts
        browser.close()
    assert errors == []
    assert requests == [html.as_uri()]
    assert screenshot.stat().st_size > 20_000


# one match of each scenario by the drive it is on, and the follower of the nuScenes scene (a recorded ego on a
# city map); the file's cyclist matches are all on the simulated junction
REPLAYS = [("follower_vehicle", "USA_US101"), ("follower_vehicle", "scene-0103"), ("sut_cut_out", "USA_US101"),
           ("cyclist_close_to_moving_sut", "junction_s1"),
           ("unprotected_left_turn_with_yield_and_traffic_light", "junction_s1")]


def test_replays_play_in_headless_chromium(matched_db, tmp_path):
    """Open a match of each scenario, play it, step, scrub: the frame, the ego and the picture move; the console
    stays clean; a screenshot per scenario is kept."""
    sync_playwright = _chromium()
    html = tmp_path / "report.html"
    shots = Path(os.environ.get("LOGIQ_SQL_SCREENSHOT_DIR") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    assert main(["report", "--db", str(matched_db), "--out", str(html)]) == 0
    errors, requests, seen = [], [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 1000})
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.on("request", lambda req: requests.append(req.url))
        page.goto(html.as_uri())
        page.wait_for_load_state("load")
        state = "window.logiqReplay.state"
        for scenario, drive in REPLAYS:
            row = page.locator(f'#matches tbody tr[data-scenario="{scenario}"]', has_text=drive).first
            row.locator("button[data-replay]").click()
            page.wait_for_function("document.getElementById('replay').dataset.ready")
            start, picture = page.evaluate(state), page.evaluate("document.getElementById('replay-canvas').toDataURL()")
            assert start["frame"] == 0 and start["n"] > 5 and drive in page.text_content("#replay-title")
            page.click("#replay-play")
            assert page.evaluate(state)["playing"]
            page.wait_for_function(f"{state}.frame >= 5")
            page.click("#replay-play")  # pause
            played = page.evaluate(state)
            assert not played["playing"] and played["frame"] >= 5
            page.click("#replay-next")
            assert page.evaluate(state)["frame"] == played["frame"] + 1
            page.click("#replay-back")
            page.click("#replay-back")
            assert page.evaluate(state)["frame"] == played["frame"] - 1
            page.eval_on_selector("#replay-slider", "s => { s.value = s.max; s.dispatchEvent(new Event('input')); }")
            end = page.evaluate(state)
            assert end["frame"] == start["n"] - 1
            # over the whole replay the ego moved (the view follows it) and the actor's box moved on the screen; not
            # within the first frames: a left turn begins with the ego, and often the actor, standing at the green
            assert math.dist(end["ego"], start["ego"]) > 0.3
            assert end["actorPx"] != start["actorPx"]
            assert page.evaluate("document.getElementById('replay-canvas').toDataURL()") != picture
            page.eval_on_selector("#replay-slider", "s => { s.value = Math.floor(s.max * 0.6); "
                                  "s.dispatchEvent(new Event('input')); }")
            page.screenshot(path=str(shots / f"replay_{scenario}_{drive}.png"))
            seen.append(page.evaluate(state)["match"])
            page.click("#replay-close")
        browser.close()
    assert errors == []
    assert requests == [html.as_uri()]
    assert len(set(seen)) == len(REPLAYS)
    assert all((shots / f"replay_{s}_{d}.png").stat().st_size > 20_000 for s, d in REPLAYS)


def test_a_missing_chromium_fails_in_ci_rather_than_skipping(monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "CHROMIUM", "/nonexistent/chromium")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="apt-get install -y chromium"):
        _chromium()


def test_a_matched_file_describes_every_table_and_column(matched_db):
    with duckdb.connect(str(matched_db), read_only=True) as con:
        bare_columns = con.execute("select table_name, column_name from duckdb_columns() "
                                   "where comment is null and not internal").fetchall()
        bare_tables = con.execute("select table_name from duckdb_tables() where comment is null union all "
                                  "select view_name from duckdb_views() where comment is null and not internal"
                                  ).fetchall()
        ttc = con.execute("select comment from duckdb_columns() where table_name = 'relations' "
                          "and column_name = 'ttc_s'").fetchone()[0]
    assert bare_columns == [] and bare_tables == []
    assert ttc.startswith("lon_gap / closing speed")  # from the header of queries/relations/relations.sql
