"""The front door (issue 35): the README's commands and examples run as written and print what it shows; the CLI's
--version, help, closed pipes, $LOGIQ_SQL_DB, query formats, info, new-scenario, scenarios --format json and the
harness under `eval`; the Python API's keyword-only options, read-only connect and errors in Python's names."""

from __future__ import annotations

import inspect
import json
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import duckdb
import pytest

import logiq_sql as lq
from logiq_sql.cli import EXIT_BAD_INPUT, EXIT_OK, main
from logiq_sql.core.errors import LogiqError, ScenarioError

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
SCENE = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b/USA_US101-22_1_T-1.xml.gz"
STAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00")
# what the step cache keeps is a CPU-time decision (docs/operations.md, "The step cache"): its counts vary by machine
# and load, and the "(N of them cheaper to recompute than to keep)" remark is printed only when N > 0
NOT_KEPT = re.compile(r" \(\d+ of them cheaper to recompute than to keep\)")
KEPT = re.compile(r"[\d,]+ rows kept in \d+ table\(s\)")


def same(line: str) -> str:
    """A printed line without what varies from run to run: timestamps, and what the step cache chose to keep."""
    return KEPT.sub("K", NOT_KEPT.sub("", STAMP.sub("T", line.rstrip())))


def blocks(language: str) -> list[str]:
    return re.findall(rf"(?ms)^```{language}\n(.*?)^```", README)


def console_steps() -> list[tuple[str, list[str]]]:
    """(command, the output lines the README shows under it) of every ```console block."""
    steps: list[tuple[str, list[str]]] = []
    for block in blocks("console"):
        for line in block.splitlines():
            if line.startswith("$ "):
                steps.append((line[2:], []))
            else:
                steps[-1][1].append(line)
    return steps


def in_checkout_copy(folder: Path) -> Path:
    """A folder where the README's relative paths (tests/data/...) resolve, without writing into the checkout."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "tests").symlink_to(ROOT / "tests")
    return folder


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> tuple[Path, list[tuple[str, list[str], str]]]:
    """The README's walk-through run as written in a fresh folder: (folder, [(command, shown, printed)])."""
    folder = in_checkout_copy(tmp_path_factory.mktemp("walk") / "here")
    done = []
    for command, shown in console_steps():
        argv = shlex.split(command)
        assert argv[0] == "logiq-sql", command
        run = subprocess.run([sys.executable, "-m", "logiq_sql.cli", *argv[1:]], cwd=folder, capture_output=True,
                             text=True, env=_env())
        assert run.returncode == EXIT_OK, (command, run.stderr)
        done.append((command, shown, run.stdout))
    return folder, done


def _env(**extra: str) -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


# --- the README ---------------------------------------------------------------------------------------------------

def test_readme_is_a_front_page():
    assert 100 <= len(README.splitlines()) <= 150
    for heading in ("## Install", "## A walk-through", "## In SQL", "## In Python", "## Exit codes",
                    "## Data and licences"):
        assert heading in README
    assert "make demo" in README and "make test" in README
    assert len(console_steps()) == 5
    for link in re.findall(r"\]\(([^)#]+)", README):  # every link points at a file of the repository
        assert (ROOT / link).exists(), link


def test_readme_walk_through_prints_what_it_shows(walk):
    _, done = walk
    for command, shown, printed in done:
        assert [same(s) for s in shown] == [same(p) for p in printed.splitlines()], command


def test_readme_sql_runs_on_the_walk_through_file(walk):
    folder, _ = walk
    (sql,) = blocks("sql")
    with lq.connect(folder / "drives.duckdb") as con:
        con.sql(sql).fetchall()  # the follower TTC query: valid against the tables


def test_readme_python_runs_as_written(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(in_checkout_copy(tmp_path / "py"))
    (code,) = blocks("python")
    exec(compile(code, "README.md", "exec"), {})
    printed = capsys.readouterr().out
    assert "scene-0103" in printed and "cyclist_close_to_moving_sut" in printed


def test_readme_sh_blocks_name_real_targets_and_extras():
    makefile = (ROOT / "Makefile").read_text()
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for block in blocks("sh"):
        for line in block.splitlines():
            argv = shlex.split(line, comments=True)
            if argv[:1] == ["make"]:
                assert re.search(rf"(?m)^{argv[1]}:", makefile), line
            elif argv[:2] == ["pip", "install"] and "[" in argv[2]:
                assert set(argv[2].split("[")[1].rstrip("]").split(",")) <= set(extras), line
            else:
                assert argv[:2] == ["pip", "install"], f"a README command no test runs: {line}"


# --- the command line -----------------------------------------------------------------------------------------------

def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out == f"logiq-sql {version}\n" and lq.__version__ == version


def test_bare_command_prints_help(capsys):
    assert main([]) == EXIT_OK
    out = capsys.readouterr().out
    assert out.startswith("usage: logiq-sql") and "  eval " in out and "  info " in out
    assert "  simulate " not in out and "  evaluate " not in out  # the harness is under eval


def test_a_closed_pipe_ends_quietly(tmp_path):
    db = tmp_path / "x.duckdb"
    lq.connect(db, read_only=False).close()
    proc = subprocess.Popen([sys.executable, "-m", "logiq_sql.cli", "query", "--db", str(db), "--format", "csv",
                             "select range as n from range(500000)"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=_env())
    assert proc.stdout.readline() == b"n\n"
    proc.stdout.close()  # as `| head -1` does
    assert proc.wait(timeout=120) == EXIT_OK
    assert proc.stderr.read() == b""


def test_db_from_the_environment(tmp_path, monkeypatch, capsys):
    db = tmp_path / "x.duckdb"
    lq.connect(db, read_only=False).close()
    monkeypatch.delenv("LOGIQ_SQL_DB", raising=False)
    assert main(["query", "select 1 as one"]) == EXIT_BAD_INPUT
    assert "pass --db FILE or set LOGIQ_SQL_DB=FILE" in capsys.readouterr().err
    monkeypatch.setenv("LOGIQ_SQL_DB", str(db))
    assert main(["query", "select 1 as one", "--format", "csv"]) == EXIT_OK
    assert capsys.readouterr().out == "one\n1\n"
    assert main(["info"]) == EXIT_OK
    assert f"{db}: 0 drive(s), 0 track rows" in capsys.readouterr().out
    monkeypatch.setenv("LOGIQ_SQL_DB", str(tmp_path / "other.duckdb"))
    assert main(["query", "--db", str(db), "select 2 as two", "--format", "csv"]) == EXIT_OK  # --db wins
    assert capsys.readouterr().out == "two\n2\n"


@pytest.fixture
def empty_db(tmp_path) -> str:
    db = tmp_path / "x.duckdb"
    lq.connect(db, read_only=False).close()
    return str(db)


SMALL = "select 0.004::double as ttc_s, 1/3 as third, 'a' as s"


@pytest.mark.parametrize(("fmt", "expected"), [
    ("csv", "ttc_s,third,s\n0.004,0.3333333333333333,a\n"),
    ("json", '[\n {\n  "ttc_s": 0.004,\n  "third": 0.3333333333333333,\n  "s": "a"\n }\n]\n'),
])
def test_query_formats_keep_every_digit(empty_db, capsys, fmt, expected):
    assert main(["query", "--db", empty_db, SMALL, "--format", fmt]) == EXIT_OK
    assert capsys.readouterr().out == expected


def test_query_table_and_markdown_keep_every_digit(empty_db, capsys):
    assert main(["query", "--db", empty_db, SMALL]) == EXIT_OK
    table = capsys.readouterr().out
    assert "0.004" in table and "0.3333333333333333" in table and "0.00 " not in table
    assert main(["query", "--db", empty_db, SMALL, "--format", "markdown"]) == EXIT_OK
    assert capsys.readouterr().out.splitlines()[::2] == ["| ttc_s | third              | s |",
                                                        "| 0.004 | 0.3333333333333333 | a |"]


def test_query_says_when_rows_were_left_out(empty_db, capsys):
    many = "select range as n from range(100)"
    assert main(["query", "--db", empty_db, many]) == EXIT_OK
    out, err = capsys.readouterr()
    assert "│ 39  │" in out and "│ 40  │" not in out
    assert err == "logiq-sql: 40 of 100 rows shown (--limit N for more, --limit 0 for all)\n"
    assert main(["query", "--db", empty_db, many, "--limit", "0"]) == EXIT_OK
    out, err = capsys.readouterr()
    assert "│ 99  │" in out and err == ""
    assert main(["query", "--db", empty_db, many, "--format", "csv"]) == EXIT_OK  # every row unless --limit
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 101 and err == ""
    assert main(["query", "--db", empty_db, many, "--format", "csv", "--limit", "5"]) == EXIT_OK
    out, err = capsys.readouterr()
    assert out.splitlines()[1:] == ["0", "1", "2", "3", "4"] and "5 of 100 rows shown" in err


def test_info_says_what_the_file_holds(walk, capsys):
    folder, _ = walk
    assert main(["info", "--db", str(folder / "drives.duckdb")]) == EXIT_OK
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == "  scenarionet: 4 (matched 3, no_match 1)"
    assert lines[2].startswith("match runs: 2 (")  # the walk-through's two runs
    assert "  cyclist_close_to_moving_sut: 1 match(es) in 1 of 4 drive(s)" in lines


def test_scenarios_as_json_with_descriptions(capsys):
    assert main(["scenarios", "--format", "json", "--all"]) == EXIT_OK
    found = {s["name"]: s for s in json.loads(capsys.readouterr().out)}
    assert found["logiq_base_scenario"]["abstract"] and not found["follower_vehicle"]["abstract"]
    params = {p["name"]: p for p in found["cyclist_close_to_moving_sut"]["params"]}
    assert params["max_distance_from_cyclist"]["default"] == "5m"
    assert params["max_distance_from_cyclist"]["type"] == "length"
    toml = tomllib.loads((ROOT / "scenarios/cyclist_close_to_moving_sut.toml").read_text())
    assert params["max_distance_from_cyclist"]["description"] == toml["params"]["max_distance_from_cyclist"][
        "description"]
    assert main(["scenarios"]) == EXIT_OK  # the table shows it too, under the parameter
    assert "        " + toml["params"]["max_distance_from_cyclist"]["description"] in capsys.readouterr().out


def test_new_scenario_passes_lint_and_matches(tmp_path, capsys):
    folder = tmp_path / "mine"
    assert main(["new-scenario", "close_follower", "--extends", "logiq_base_lane_following_scenario",
                 "--dir", str(folder)]) == EXIT_OK
    assert sorted(p.name for p in folder.iterdir()) == ["close_follower.sql", "close_follower.toml"]
    assert main(["lint", "close_follower", "--scenario-path", str(folder)]) == EXIT_OK
    db = tmp_path / "x.duckdb"
    lq.ingest("commonroad", [SCENE], db)
    result = lq.match(db, scenarios=["close_follower"], scenario_path=folder, ego="every:5")
    assert result.matches.height > 0
    assert (result.matches["duration_s"] >= 1.0).all()  # its min_close_follow_duration
    capsys.readouterr()
    assert main(["new-scenario", "close_follower", "--dir", str(folder)]) == EXIT_BAD_INPUT  # never overwrites
    assert "exists already" in capsys.readouterr().err
    assert main(["new-scenario", "Close-Follower", "--dir", str(folder)]) == EXIT_BAD_INPUT
    assert "logiq-sql: error: NAME Close-Follower: write the name in lower case" in capsys.readouterr().err
    with pytest.raises(ScenarioError, match=r"extends='logiq_base_object_scenario': .* needs the kinds parameter"):
        from logiq_sql.spec.scaffold import new_scenario
        new_scenario("near_object", "logiq_base_object_scenario", tmp_path / "other")


def test_the_harness_is_under_eval(capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["eval", "label", "--help"])
    assert "usage: logiq-sql eval label" in capsys.readouterr().out
    # the old name still runs, with a one-line notice on stderr
    assert main(["evaluate", "--db", str(tmp_path / "none.duckdb"), "--labels", str(tmp_path / "l.parquet")]) != 0
    assert capsys.readouterr().err.splitlines()[0] == ("logiq-sql: `evaluate` is now `logiq-sql eval evaluate`; the "
                                                       "old name will be removed.")


# --- the Python API -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("function", "positional"), [
    (lq.match, 1), (lq.match_dataset, 3), (lq.render, 1), (lq.ingest, 3), (lq.match_frames, 1), (lq.connect, 1)])
def test_options_are_keyword_only(function, positional):
    params = list(inspect.signature(function).parameters.values())
    assert [p.name for p in params[:positional]] == [p.name for p in params
                                                     if p.kind is p.POSITIONAL_OR_KEYWORD], function.__name__
    assert all(p.kind in (p.KEYWORD_ONLY, p.VAR_KEYWORD) for p in params[positional:]), function.__name__


def test_match_refuses_options_by_position(tmp_path):
    with pytest.raises(TypeError):
        lq.match(tmp_path / "x.duckdb", ["follower_vehicle"])


@pytest.mark.parametrize(("kwargs", "python", "cli", "argv"), [
    ({"overrides": {"same_road_limit": "10"}}, "overrides['same_road_limit']='10': '10' has no unit",
     "--set same_road_limit=10: '10' has no unit", ["--set", "same_road_limit=10"]),
    ({"relation_range": "200"}, "relation_range='200': '200' has no unit",
     "--relation-range 200: '200' has no unit", ["--relation-range", "200"]),
    ({"ego": "every:0"}, "ego='every:0': N in every:N", "--ego every:0: N in every:N", ["--ego", "every:0"]),
    ({"ego_kinds": "car,trucks"}, "ego_kinds='car,trucks': 'trucks' is not",
     "--ego-kinds car,trucks: 'trucks' is not", ["--ego-kinds", "car,trucks"]),
])
def test_errors_name_the_python_argument_and_the_cli_flag(capsys, kwargs, python, cli, argv):
    with pytest.raises(LogiqError) as e:
        lq.render("follower_vehicle", **kwargs)
    assert str(e.value).startswith(python) and "--" not in str(e.value).split(":")[0]
    assert main(["render", "follower_vehicle", *argv]) == EXIT_BAD_INPUT
    assert capsys.readouterr().err.startswith(f"logiq-sql: error: {cli}")


def test_an_unknown_drive_names_drives(tmp_path, capsys):
    db = tmp_path / "x.duckdb"
    lq.ingest("commonroad", [SCENE], db)
    with pytest.raises(ScenarioError, match=r"^drives='nope': no such drive in the file\."):
        lq.match(db, drives=["nope"])
    assert main(["match", "--db", str(db), "--drive", "nope"]) == EXIT_BAD_INPUT
    assert "logiq-sql: error: --drive nope: no such drive in the file.\n" in capsys.readouterr().err


def test_connect_is_read_only_unless_asked(tmp_path):
    db = tmp_path / "x.duckdb"
    with pytest.raises(LogiqError, match="no such file"):
        lq.connect(db)  # reading never creates a file
    lq.connect(db, read_only=False).close()  # creates it, with every table
    with lq.connect(db) as con:
        assert con.execute("select count(*) from drives").fetchone() == (0,)
        with pytest.raises(duckdb.Error, match="read-only"):
            con.execute("delete from drive_inputs")



def test_report_replay_and_busy_errors_name_the_python_argument(tmp_path, capsys):
    from logiq_sql.outputs import replay, report
    from logiq_sql.storage import locking

    missing = tmp_path / "none.duckdb"
    with pytest.raises(LogiqError, match=r"^db='.*none\.duckdb': no such file"):
        report.report(missing, tmp_path / "r.html")
    with pytest.raises(LogiqError, match=r"^out='.*\.png': write a \.gif or an \.mp4 file"):
        replay.save(missing, "m", tmp_path / "x.png")
    assert main(["report", "--db", str(missing), "--out", str(tmp_path / "r.html")]) == EXIT_BAD_INPUT
    assert "logiq-sql: error: --db " in capsys.readouterr().err
    db = tmp_path / "x.duckdb"
    held = locking.acquire(db)
    try:
        with pytest.raises(locking.FileBusyError, match=r"Wait for it with wait_s=60 \(seconds\)"):
            locking.acquire(db)
    finally:
        held.release()
