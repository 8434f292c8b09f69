"""One self-contained HTML report of a matched DuckDB file, for scheduled runs.

Charts are inline SVG drawn by ``logiq_sql.outputs.plots``; the match table's filter is a few lines of inline JavaScript.
Every match opens an animated replay (``logiq_sql.outputs.replay``): its scene is embedded as gzip + base64 JSON and
decoded by ``replay.js`` only when opened, so thousands of matches cost their bytes, not their drawing time.
Nothing is fetched from the network, so the file can be mailed, archived or opened offline.
"""

from __future__ import annotations

import datetime as dt
import html
import io
import json
import re
from pathlib import Path

import matplotlib
import polars as pl

from logiq_sql.core.errors import InputError, ScenarioError, arg
from logiq_sql.outputs import plots, replay
from logiq_sql.spec.scenario import load_scenario
from logiq_sql.storage.db import open_current

MATCH_COLUMNS = ("match_id", "scenario", "drive_id", "ego_id", "actor_id", "start_s", "end_s", "duration_s",
                 "params_hash")

STYLE = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 12px; }
th, td { border: 1px solid #ddd; padding: 2px 6px; text-align: left; }
th { background: #f2f2f2; position: sticky; top: 0; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.cards { display: flex; gap: 1em; flex-wrap: wrap; }
.card { border: 1px solid #ddd; border-radius: 6px; padding: .5em 1em; background: #fafafa; }
.card b { display: block; font-size: 1.4em; }
.scroll { max-height: 480px; overflow: auto; border: 1px solid #ddd; }
.chart svg { max-width: 100%; height: auto; }
.filters { margin: .5em 0; display: flex; gap: 1em; align-items: center; }
.status-rejected { color: #b00; } .status-matched { color: #060; }
button[data-replay] { font-size: 11px; padding: 0 6px; cursor: pointer; }
dialog#replay { padding: .5em 1em; border: 1px solid #888; border-radius: 6px; max-width: 1040px; }
dialog#replay::backdrop { background: rgba(0, 0, 0, .35); }
.replay-head, .replay-controls { display: flex; gap: .6em; align-items: center; margin: .3em 0; font-size: 12px; }
.replay-head span { flex: 1; } #replay-slider { flex: 1; }
.key { font-size: 11px; color: #555; }
"""

# filters the match table by scenario and by free text over every cell
SCRIPT = """
(function () {
  const rows = Array.from(document.querySelectorAll('#matches tbody tr'));
  const scenario = document.getElementById('scenario-filter');
  const text = document.getElementById('text-filter');
  const count = document.getElementById('match-count');
  function apply() {
    const s = scenario.value, t = text.value.trim().toLowerCase();
    let shown = 0;
    for (const row of rows) {
      const ok = (!s || row.dataset.scenario === s) && (!t || row.textContent.toLowerCase().includes(t));
      row.hidden = !ok;
      if (ok) shown += 1;
    }
    count.textContent = shown + ' of ' + rows.length + ' matches';
  }
  scenario.addEventListener('change', apply);
  text.addEventListener('input', apply);
  apply();
})();
"""


def _svg(fig) -> str:
    """A figure as inline SVG: text stays text, no date, stable ids, so the same data gives the same file."""
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": "logiq-sql"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    text = re.sub(r"<metadata>.*?</metadata>", "", buf.getvalue(), flags=re.DOTALL)  # RDF boilerplate
    return '<div class="chart">' + text[text.index("<svg"):] + "</div>"


def _table(frame: pl.DataFrame, table_id: str | None = None, row_attr: str | None = None,
           replays: bool = False) -> str:
    """An HTML table of ``frame``; with ``replays``, a first column of buttons opening replay k of row k."""
    numeric = {c for c, t in frame.schema.items() if t.is_numeric()}
    head = ("<th>replay</th>" if replays else "") + "".join(f"<th>{html.escape(c)}</th>" for c in frame.columns)
    body = []
    for k, row in enumerate(frame.iter_rows(named=True)):
        cells = [f'<td><button data-replay="{k}" title="replay this match">&#9654;</button></td>'] if replays else []
        for c, v in row.items():
            text = "" if v is None else (f"{v:.2f}" if isinstance(v, float) else str(v))
            css = ' class="num"' if c in numeric else (f' class="status-{html.escape(text)}"' if c == "status" else "")
            cells.append(f"<td{css}>{html.escape(text)}</td>")
        attr = f' data-{row_attr}="{html.escape(str(row[row_attr]))}"' if row_attr else ""
        body.append(f"<tr{attr}>{''.join(cells)}</tr>")
    ident = f' id="{table_id}"' if table_id else ""
    return f"<table{ident}><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _load(db: str | Path) -> dict[str, pl.DataFrame]:
    if not Path(db).is_file():
        raise InputError(f"{arg('db', db)}: no such file (write one with `logiq-sql ingest` and `logiq-sql match`).")
    with open_current(db) as con:  # one connection: the tables and the replays are of one published state
        present = {r[0] for r in con.sql("select table_name from information_schema.tables").fetchall()}
        missing = [t for t in ("matches", "kpis", "coverage", "match_runs") if t not in present]
        if missing:
            raise InputError(f"{arg('db', db)}: no match run recorded yet ({', '.join(missing)} missing): run "
                             f"`logiq-sql match --db {db}` first, then the report.")
        data = {
            "drives": con.sql("select drive_id, source_format, status, matches, matches_per_scenario, rows_read, "
                              "rows_rejected, reject_reason from drives order by status, drive_id").pl(),
            "matches": con.sql(f"select {', '.join(MATCH_COLUMNS)} from matches "
                               "order by scenario, drive_id, start_s, ego_id, actor_id").pl(),
            "kpis": con.sql("select * from kpis").pl(),
            "coverage": con.sql("select * from coverage").pl(),
            "runs": con.sql("select run_id, started_at, scenario, scenario_version, params_hash, overrides, ego_mode, "
                            "drives, matches from match_runs order by run_id desc, scenario").pl(),
        }
        data["scenes"], data["maps"] = replay.scenes(con, data["matches"]["match_id"].to_list())
    return data


def _replays(matches: pl.DataFrame, scenes: list[dict], maps: dict) -> str:
    """The replay dialog, its configuration and one packed scene per match row (``rp-<row>``), one per map
    (``rm-<k>``)."""
    by_id = {s["id"]: s for s in scenes}
    map_keys = {m: k for k, m in enumerate(maps)}
    config = {"layout": replay.LAYOUT, "style": replay.STYLE, "series": replay.SERIES, "panels": replay.PANELS,
              "key": replay.KEY, "margin_s": replay.MARGIN_S, "time_label": replay.TIME_LABEL, "maps": map_keys}
    tags = [f'<script type="application/json" id="replay-config">{_json(config)}</script>']
    tags += [f'<script type="application/x-gzip-base64" id="rm-{k}">{replay.pack(maps[m])}</script>'
             for m, k in map_keys.items()]
    tags += [f'<script type="application/x-gzip-base64" id="rp-{k}">{replay.pack(by_id[m])}</script>'
             for k, m in enumerate(matches["match_id"]) if m in by_id]
    dialog = (
        '<dialog id="replay"><div class="replay-head"><span id="replay-title"></span>'
        '<button id="replay-close">close</button></div>'
        '<div class="key">The view keeps the ego and the actor in frame over the whole match; trails: the path so '
        'far; time in seconds of the drive; docs/replay.md explains every mark.</div>'
        f'<canvas id="replay-canvas" width="{replay.LAYOUT["width"]}" height="{replay.LAYOUT["height"]}"></canvas>'
        '<div class="replay-controls"><button id="replay-back">&#9664; step</button>'
        '<button id="replay-play">play</button><button id="replay-next">step &#9654;</button>'
        '<input id="replay-slider" type="range" min="0" max="0" value="0"><span id="replay-frame"></span></div>'
        "</dialog>")
    return dialog + "\n" + "\n".join(tags)


def _units(name: str, what: str) -> dict[str, str]:
    """The unit of each coverage item (``what="coverage"``, by item) or KPI column (``"kpis"``, by column) of a
    scenario, from its file; empty for a scenario of another --scenario-path."""
    try:
        scenario = load_scenario(name)
    except ScenarioError:
        return {}
    if what == "coverage":
        return {c.name: c.unit for c in scenario.coverage}
    return {column: unit for column, (unit, _, _) in scenario.metric_columns().items()}


def _json(value: object) -> str:
    """JSON safe inside a <script> element."""
    return json.dumps(value, separators=(",", ":")).replace("</", "<\\/")


def report(db: str | Path, out: str | Path) -> Path:
    """Write the HTML report of ``db`` to ``out`` and return its path."""
    data = _load(db)
    drives, matches, runs = data["drives"], data["matches"], data["runs"]
    scenarios = sorted(set(data["coverage"]["scenario"]) | set(matches["scenario"]))
    status = drives.group_by("status").len().sort("status")
    cards = [("drives", drives.height), ("matches", matches.height), ("scenarios run", runs["scenario"].n_unique()),
             *[(f"drives {s}", n) for s, n in status.rows()]]
    parts = [
        f"<h1>logiq_sql report: {html.escape(Path(db).name)}</h1>",
        (f"<p>Written {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')} from "
         f"<code>{html.escape(str(db))}</code>. Tables and columns: docs/tables.md.</p>"),
        '<div class="cards">' + "".join(f'<div class="card"><b>{n}</b>{html.escape(k)}</div>' for k, n in cards)
        + "</div>",
        "<h2>Coverage</h2><p>Hits per bucket over every match in the file; empty buckets are shaded red.</p>",
    ]
    per_scenario = matches.group_by("scenario").len()
    counts = dict(per_scenario.iter_rows())
    for s in scenarios:
        if not counts.get(s):  # one line, not a grid of empty charts
            parts.append(f"<p class=\"none\">{html.escape(s)}: no match in this file, so no coverage.</p>")
        elif not data["coverage"].filter(pl.col("scenario") == s).is_empty():
            parts.append(_svg(plots.coverage_grid(data["coverage"], s, units=_units(s, "coverage"))))
    parts.append("<h2>KPI distributions</h2>")
    for s in scenarios:
        if counts.get(s) and plots.kpi_columns(data["kpis"], s):
            parts.append(_svg(plots.kpi_grid(data["kpis"], s, units=_units(s, "kpis"))))
        else:
            parts.append(f"<p class=\"none\">{html.escape(s)}: no match in this file, so no KPI values.</p>")
    options = "".join(f'<option value="{html.escape(s)}">{html.escape(s)}</option>' for s in scenarios)
    parts += [
        "<h2>Matches</h2>",
        ('<div class="filters"><label>scenario <select id="scenario-filter"><option value="">all</option>'
         f'{options}</select></label><label>contains <input id="text-filter" type="search" '
         'placeholder="drive, actor, ..."></label><span id="match-count"></span></div>'),
        ("<p>&#9654; opens the match's replay: lanes and junctions, the ego and the actor as boxes with their "
         "headings, the phases on a timeline, gap, headway, TTC and speeds over time (PET where the scenario "
         "measures it). Play, pause, step or drag the slider.</p>"),
        '<div class="scroll">' + _table(matches, "matches", row_attr="scenario", replays=True) + "</div>",
        "<h2>Drives</h2><p>Every drive that went in, with its status over all scenarios run.</p>",
        '<div class="scroll">' + _table(drives, "drives") + "</div>",
        "<h2>Runs</h2><p>Every match run and the parameters it used (params_json in the match_runs table).</p>",
        '<div class="scroll">' + _table(runs, "runs") + "</div>",
    ]
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>logiq_sql report: '
            f'{html.escape(Path(db).name)}</title><style>{STYLE}</style></head><body>\n' + "\n".join(parts)
            + "\n" + _replays(matches, data["scenes"], data["maps"])
            + f"\n<script>{SCRIPT}</script>\n<script>{replay.REPLAY_JS}</script>\n</body></html>\n")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out
