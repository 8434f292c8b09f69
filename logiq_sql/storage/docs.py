"""The docs generated from the code's declarations (`make docs`, ``python -m logiq_sql.storage.docs``):
docs/tables.md from the tables', the table of formats in docs/formats.md from the reader registry."""

from __future__ import annotations

from pathlib import Path

from logiq_sql.core.formats import formats_markdown
from logiq_sql.core.schema import Table, duckdb_type
from logiq_sql.storage.tables import DRIVES_DOC, STEP_CACHE, TABLES


def _described(table: Table) -> list[str]:
    """A table's description and its columns' table, as markdown lines."""
    return [table.doc, "", "| column | type | meaning |", "|---|---|---|",
            *[f"| `{c.name}` | {duckdb_type(c.dtype).lower()} | {c.doc} |" for c in table.columns], ""]


def docs_markdown() -> str:
    """The tables as a markdown page (docs/tables.md is generated from this by `make docs`)."""
    out = ["# Tables in the logiq_sql DuckDB file", "",
           "Generated from `logiq_sql/core/schema.py` and `logiq_sql/storage/tables.py` (`make docs`). Every column also carries "
           "this text as a DuckDB comment: `select * from duckdb_columns() where comment is not null`.", ""]
    for table in TABLES:
        out += [f"## `{table.name}`", "", *_described(table)]
    out += ["## `kpis`", "",
            "One row per match: `match_id`, `scenario`, then every KPI and sampled coverage value of the scenarios "
            "in `scenarios/`, in the spec's units (the suffix); NULL where a scenario does not record it or the "
            "value is undefined. Columns are added as scenarios are run.", "",
            "| column | unit | meaning |", "|---|---|---|"]
    from logiq_sql.spec.scenario import list_scenarios

    seen: set[str] = set()
    for s in list_scenarios():
        for column, (unit, _sql_type, doc) in s.metric_columns().items():
            if column not in seen:
                seen.add(column)
                out.append(f"| `{column}` | {unit} | {doc} |")
    out += ["", "## `relations` and `ego_lanes`", "",
            "Kept from the last match run of each drive, for analysts: see docs/semantics.md for every column "
            "(`queries/relations/relations.sql`, `queries/relations/ego_lanes.sql`). In the file, their columns carry "
            "the descriptions of those files' headers as comments (as do `passages` and `encroachments`).", "",
            ("`relations` (kept with `match --keep`) holds the actors of the kinds some scenario of that run can use: "
             "the union of the scenarios' `relation_kinds` (docs/scenarios.md), every kind when one of them leaves "
             "it unset, as every built-in scenario but `cyclist_close_to_moving_sut` (`relation_kinds = "
             "[\"cyclist\"]`) does. A run of the cyclist scenario alone keeps its cyclists only; a run with any "
             "other keeps the full relation. `relations_of(drive_id, ego_id)`, a table macro `match` creates in the "
             "file, gives the full relation of any ego on demand (`logiq_sql/matching/relations_of.py`)."), "",
            "## `passages` and `encroachments`", "",
            "Kept from the last run of a junction scenario on each drive: every stay of an ego or related actor in a "
            "junction with its entry and exit, legs and turn (`queries/junctions/passages.sql`), and the encroachment "
            "area of every ego-actor pair whose paths through a junction cross, as WKT with the stretch of each "
            "path along which its box overlaps the area (`logiq_sql/matching/encroachment.py`). Definitions: docs/semantics.md, unprotected_left_turn_with_yield_and_"
            "traffic_light.", "",
            "## The step cache: `step_cache` and `step_cache_<key>`, in `<file>.step_cache`", "",
            "The step cache is a DuckDB file of its own beside the file (`drives.duckdb.step_cache` for "
            "`drives.duckdb`), which only the run holding the file's writer lock opens: a run's working copy of the "
            "file leaves it out. To read it, stop writing runs and `attach 'drives.duckdb.step_cache' as cache "
            "(read_only)`; `logiq-sql cache --db FILE` gives its size.", "",
            f"### `{STEP_CACHE.name}`", "", *_described(STEP_CACHE),
            "### `step_cache_<key>`", "",
            "The rows of one step of a match run, for every drive whose `step_cache` entry names the table: the "
            "columns of the step's query (`queries/...`, named in `step_cache.step`), a `drive_id` among them, or, "
            "for a step whose rows carry only `drive_key`, `cached_drive_id` beside them. "
            "`match` reads them back instead of running the step again when the step's query text, bound values "
            "and inputs and the drive's ingest version are the same (`logiq_sql/storage/step_cache.py`; README, 'The step "
            "cache'). Rows no entry refers to are deleted, a table with none dropped; `logiq-sql cache --db FILE` "
            "gives their size, `--clear` drops them all.", "",
            "## `drives` (view)", "",
            "Every drive of `drive_inputs` with its status over all scenarios run: " + DRIVES_DOC["status"], ""]
    return "\n".join(out)


FORMATS_BEGIN = "<!-- the formats: generated from logiq_sql/core/formats.py by `make docs`; edit them there -->"
FORMATS_END = "<!-- end of the formats -->"


def with_formats(page: str) -> str:
    """docs/formats.md's text ``page`` with its table of formats (between FORMATS_BEGIN and FORMATS_END) as the
    reader registry gives it."""
    before, begin, rest = page.partition(FORMATS_BEGIN + "\n")
    _old, end, after = rest.partition(FORMATS_END)
    if not begin or not end:
        raise ValueError(f"docs/formats.md: the lines {FORMATS_BEGIN} and {FORMATS_END} are missing")
    return before + begin + formats_markdown() + "\n" + end + after


def write_docs(root: Path) -> None:
    """docs/tables.md and the table of formats in docs/formats.md under ``root`` (the repository)."""
    (root / "docs/tables.md").write_text(docs_markdown() + "\n")
    formats = root / "docs/formats.md"
    formats.write_text(with_formats(formats.read_text()))


if __name__ == "__main__":
    write_docs(Path.cwd())
