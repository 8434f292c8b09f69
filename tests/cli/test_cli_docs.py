"""The CLI and the documentation that users read stay in step with the code."""

from __future__ import annotations

from pathlib import Path

import duckdb
import pytest

from logiq_sql.cli import main
from logiq_sql.storage.db import connect
from logiq_sql.storage.docs import docs_markdown, with_formats

ROOT = Path(__file__).resolve().parents[2]


def test_tables_doc_is_current():
    assert (ROOT / "docs/tables.md").read_text() == docs_markdown() + "\n", "run `make docs`"


def test_formats_doc_is_the_reader_registry():
    page = (ROOT / "docs/formats.md").read_text()
    assert page == with_formats(page), "run `make docs`: docs/formats.md's table of formats is not the registry's"


def test_every_column_has_a_comment(tmp_path):
    connect(tmp_path / "x.duckdb").close()
    with duckdb.connect(str(tmp_path / "x.duckdb"), read_only=True) as con:
        bare = con.execute("select table_name, column_name from duckdb_columns() "
                           "where comment is null and not internal").fetchall()
    assert bare == []


@pytest.mark.parametrize("command", ["ingest", "match", "scenarios", "render", "explain", "query"])
def test_help(command, capsys):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    assert "usage: logiq-sql " + command in capsys.readouterr().out


def test_scenarios_lists_parameters_with_units_and_defaults(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    assert "--set max_distance_from_cyclist=...  length, default 5m  [cyclist_close_to_moving_sut]" in out
    assert "--set min_distance_from_sut_in_time_units=...  time, default 0sec  [logiq_base_lane_following_scenario]" in out
    assert "--set kinds=...  kinds, default (no default)  [logiq_base_vehicle_scenario]" in out


def test_end_to_end_through_the_cli(tmp_path, capsys):
    data = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
    db = str(tmp_path / "cli.duckdb")
    assert main(["ingest", "commonroad", str(data), "--db", db, "--quiet"]) == 0
    assert main(["match", "--db", db, "--scenario", "follower_vehicle", "--ego", "671", "--out",
                 str(tmp_path / "out"), "--quiet"]) == 0
    out = capsys.readouterr().out
    # the nearest car behind 671: 675 until it leaves the lane at 9.4 s, then 691
    assert "follower_vehicle: 2 matches in 1 drive(s)" in out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "coverage.parquet", "coverage_samples.parquet", "drive_scenarios.parquet", "drives.parquet",
        "kpis.parquet", "match_phases.parquet", "match_runs.parquet", "matches.parquet"]
    assert main(["query", "--db", db, "select actor_id, start_s, end_s from matches order by actor_id"]) == 0
    printed = capsys.readouterr().out
    assert "675" in printed and "691" in printed


def test_every_source_format_is_named_where_users_read_it():
    """One registry (core/formats.py): the CLI's choices, its help and the source_format column's doc list every
    format, and each has its reader module with read_<name> (the column doc once listed 5 of the 7)."""
    import importlib

    from logiq_sql.cli import build_parser
    from logiq_sql.core import schema
    from logiq_sql.core.formats import FORMATS

    ingest = build_parser()._subparsers._group_actions[0].choices["ingest"]
    (fmt,) = [a for a in ingest._actions if a.dest == "format"]
    assert list(fmt.choices) == list(FORMATS)
    doc = next(c.doc for c in schema.DRIVE_INPUTS.columns if c.name == "source_format")
    for name, source in FORMATS.items():
        assert f"{name}: " in fmt.help and name in doc, name
        module = importlib.import_module(f"logiq_sql.ingestion.readers.{name}")
        assert callable(getattr(module, f"read_{name}")), name
        assert source.folders is None or callable(getattr(module, source.folders)), name
