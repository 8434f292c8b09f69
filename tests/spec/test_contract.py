"""The scenario contract, checked before any data is read: every key of every TOML table, the placeholders each
SQL file uses, the columns each phase, KPI and sample query returns; `logiq-sql lint`; a user's own folder of
scenarios (--scenario-path); and every scenario in scenarios/ found and run without a list of names."""

from __future__ import annotations

from pathlib import Path

import pytest

from logiq_sql.cli import main
from logiq_sql.cli.lint import lint_scenarios
from logiq_sql.core.errors import ScenarioError
from logiq_sql.matching.match import match, render
from logiq_sql.spec.plan import resolve_scenarios
from logiq_sql.spec.scenario import list_scenarios, load_scenario, scenario_files
from tests.helpers import Y1, actor, intervals, make_db, times

# a user's scenario: a follower that may be at most 2 s behind, with its own phase query beside the TOML file
OWN_TOML = '''name = "close_follower"
extends = ["logiq_base_lane_following_scenario"]
description = "A follower at most 2 s behind."
version = 1

[params.min_follow]
type = "time"
default = "1s"
description = "shortest episode"

[[phases]]
name = "close_follower"
query = "close_follower.sql"
min_duration = "min_follow"
conditions = [{ name = "close", value = "time_headway_s", test = "<= 2 s" }]
'''
OWN_SQL = '''-- phase: close_follower (a user's own)
with

conditions as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.drive_key,
        r.ego_key,
        r.actor_key,
        r.frame,
        r.t_s,
        0 as segment,
        coalesce(r.time_headway_s <= 2.0 and r.same_lane and r.dx_m < 0, false) as close,
        r.time_headway_s
    from relations as r
    where instr($kinds_csv, ',' || r.actor_kind || ',') > 0
)

select *, close as holds from conditions
'''


def own_folder(tmp: Path, toml: str = OWN_TOML, sql: str = OWN_SQL) -> Path:
    folder = tmp / "mine"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "close_follower.toml").write_text(toml)
    (folder / "close_follower.sql").write_text(sql)
    return folder


def test_every_scenario_in_the_folder_is_found_and_passes_lint():
    names = sorted(scenario_files())
    assert "cut_in_ahead_of_ego" in names and "sut_cut_out" in names
    assert lint_scenarios() == []
    for s in list_scenarios():  # every concrete scenario renders to SQL without a list of names here
        assert "select" in render(s.name)


@pytest.mark.parametrize("scenario", [s.name for s in list_scenarios()])
def test_every_scenario_runs_on_a_small_drive(tmp_path, scenario):
    """Discovered from scenarios/: a new scenario file is run here without a Python edit."""
    t = times(4.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, 80 + 10 * t, Y1)])
    result = match(db, scenarios=[scenario])
    assert result.drives["status"].to_list()[0] in ("matched", "no_match")


def test_a_misspelt_key_in_a_phase_is_an_error(tmp_path):
    folder = own_folder(tmp_path, OWN_TOML.replace("min_duration =", "min_durration ="))
    with pytest.raises(ScenarioError) as e:
        load_scenario("close_follower", folder)
    assert "[[phases]] close_follower: unknown key 'min_durration'. Did you mean 'min_duration'?" in str(e.value)


@pytest.mark.parametrize(("table", "bad", "fix"), [
    ("[[kpis]]", '[[kpis]]\nname = "k"\ncolumn = "k_s"\nunit = "s"\ndescripton = "x"\n', "description"),
    ("[[coverage]]", '[[coverage]]\nname = "c"\ncolumn = "c_m"\nunit = "m"\nrange = [0, 1]\nevry = 1\n', "every"),
])
def test_a_misspelt_key_in_kpis_or_coverage_is_an_error(tmp_path, table, bad, fix):
    folder = own_folder(tmp_path, OWN_TOML + bad)
    with pytest.raises(ScenarioError, match=f"{table.replace('[', '.').replace(']', '.')}.*Did you mean '{fix}'"):
        load_scenario("close_follower", folder)


def test_an_enum_kpi_needs_a_declared_type(tmp_path):
    kpi = '[[kpis]]\nname = "side"\ncolumn = "side"\nunit = "av_side"\n'
    with pytest.raises(ScenarioError, match="unit 'av_side' is neither a unit of measure nor text; declare type"):
        load_scenario("close_follower", own_folder(tmp_path, OWN_TOML + kpi))
    s = load_scenario("close_follower", own_folder(tmp_path / "b", OWN_TOML + kpi + 'type = "text"\n'))
    assert s.metric_columns()["side"][1] == "varchar"


def test_sql_that_does_not_fit_the_scenario_is_refused_before_any_data_is_read(tmp_path):
    no_segment = own_folder(tmp_path / "a", sql=OWN_SQL.replace("        0 as segment,\n", ""))
    with pytest.raises(ScenarioError, match="close_follower.sql: does not return column 'segment'"):
        resolve_scenarios(["close_follower"], {}, no_segment)
    typo = own_folder(tmp_path / "b", sql=OWN_SQL.replace("$kinds_csv", "$kind_csv"))
    with pytest.raises(ScenarioError, match=r"uses \$kind_csv, which no parameter .* Did you mean 'kinds_csv'"):
        resolve_scenarios(["close_follower"], {}, typo)
    kpi = '[[kpis]]\nname = "k"\ncolumn = "k_s"\nunit = "s"\n'
    with pytest.raises(ScenarioError, match=r"\[\[kpis\]\] k: column 'k_s' is returned by none"):
        resolve_scenarios(["close_follower"], {}, own_folder(tmp_path / "c", OWN_TOML + kpi))
    unlisted = own_folder(tmp_path / "d", OWN_TOML.replace('name = "close", value', 'name = "closer", value'))
    with pytest.raises(ScenarioError, match="does not return column 'closer' .a condition named in conditions."):
        resolve_scenarios(["close_follower"], {}, unlisted)
    # match refuses it the same way, before it opens the file (there is none)
    with pytest.raises(ScenarioError):
        match(tmp_path / "none.duckdb", scenarios=["close_follower"], scenario_path=no_segment)


def test_lint_command_names_file_and_key_and_exits_2(tmp_path, capsys):
    bad = own_folder(tmp_path / "a", sql=OWN_SQL.replace("        0 as segment,\n", ""))
    assert main(["lint", "close_follower", "--scenario-path", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad / 'close_follower.toml'} [[phases]] close_follower" in err and "'segment'" in err
    assert main(["lint", "--scenario-path", str(own_folder(tmp_path / "b"))]) == 0


def test_a_users_own_folder_runs_with_the_built_in_bases(tmp_path, capsys):
    folder = own_folder(tmp_path)
    t = times(5.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("near", t, 85 + 10 * t, Y1)])
    result = match(db, scenarios=["close_follower"], scenario_path=folder)
    assert intervals(result.matches, "close_follower") == [("ego", "near", 0.0, 5.0)]
    assert result.kpis["vehicle_tracking_id"].to_list() == ["near"]  # inherited from logiq_base_vehicle_scenario
    assert main(["render", "close_follower", "--scenario-path", str(folder)]) == 0
    assert "as segment" in capsys.readouterr().out
    assert main(["explain", "--db", str(db), "--scenario", "close_follower", "--drive", "d1", "--ego", "ego",
                 "--scenario-path", str(folder)]) == 0
    assert "ego ego, actor near: 1 of 1 phases -- matched" in capsys.readouterr().out
    with pytest.raises(ScenarioError, match="scenario 'close_follower' not found"):
        load_scenario("close_follower")  # not without the folder


def test_holds_is_exactly_the_and_of_the_listed_conditions(tmp_path, capsys):
    """A phase whose `holds` tests a condition its [[phases]] entry does not list (follower_vehicle's
    actor_path_follows_ego once) could never be named by explain: lint and match refuse it, naming the condition;
    so does a listed condition holds leaves out, and a holds that is not a plain AND of condition columns."""
    hidden = OWN_SQL.replace("close as holds", "close and r_far as holds").replace(
        "        r.time_headway_s\n", "        r.time_headway_s,\n        r.dx_m < -100 as r_far\n")
    with pytest.raises(ScenarioError, match="holds ANDs 'r_far', which conditions does not list: add it there"):
        resolve_scenarios(["close_follower"], {}, own_folder(tmp_path / "a", sql=hidden))
    unused = OWN_TOML.replace('test = "<= 2 s" }]', 'test = "<= 2 s" }, { name = "segment", value = "t_s", test = "x" }]')
    with pytest.raises(ScenarioError, match="conditions lists 'segment', which holds does not AND"):
        resolve_scenarios(["close_follower"], {}, own_folder(tmp_path / "b", unused))
    inline = OWN_SQL.replace("close as holds", "coalesce(close, false) as holds")
    assert main(["lint", "--scenario-path", str(own_folder(tmp_path / "c", sql=inline))]) == 2
    assert "holds must be the AND of the condition columns" in capsys.readouterr().err
