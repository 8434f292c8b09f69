"""For analysts and scheduled reports: the example queries of docs/queries.md, the query command, and the HTML
report opened in headless Chromium."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import duckdb
import pytest

from logiq_sql import ingest, match
from logiq_sql.cli import main

ROOT = Path(__file__).resolve().parents[1]
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
def matched_db(tmp_path_factory) -> Path:
    return build_matched_db(tmp_path_factory.mktemp("analysts") / "drives.duckdb")


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
    # two cut-outs of these scenes qualify: ego 40 in US-101 scene 26 and ego 44 in scene 24
    assert sorted(rows.select("drive_id", "ego_id").rows()) == [
        ("USA_US101-24_1_T-1@2018b", "44"), ("USA_US101-26_1_T-1@2018b", "40")]
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
        # coverage grids for the 4 scenarios and KPI grids for the 4 that matched
        assert page.locator(".chart svg").count() == 8
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
