"""Error messages, asserted verbatim: each names the file, key or column, and the fix."""

from __future__ import annotations

import polars as pl
import pytest

from logiq_sql.cli import main
from logiq_sql.core import units
from logiq_sql.core.errors import InputError, ScenarioError, UnitError
from logiq_sql.ingestion.readers.parquet import read_parquet
from logiq_sql.matching.match import resolve_scenarios
from logiq_sql.spec.scenario import load_scenario


def message(exc_info) -> str:
    return str(exc_info.value)


def test_wrong_unit_for_a_length():
    with pytest.raises(UnitError) as e:
        resolve_scenarios(["cyclist_close_to_moving_sut"], {"max_distance_from_cyclist": "4kph"})
    assert message(e) == ("overrides['max_distance_from_cyclist']='4kph': '4kph' is a speed, but this parameter is a length."
                          "\n\nHint: use a length unit such as 'm'.")


def test_missing_unit():
    with pytest.raises(UnitError) as e:
        resolve_scenarios(["follower_vehicle"], {"same_road_limit": "10"})
    assert message(e) == ("overrides['same_road_limit']='10': '10' has no unit; a time needs one.\n\n"
                          "Hint: write it with a unit, e.g. \"10 s\".")


def test_unknown_unit():
    with pytest.raises(UnitError) as e:
        units.parse("3 furlongs", "length", "x.toml [params.a]")
    assert message(e) == ("x.toml [params.a]: unknown unit 'furlongs' in '3 furlongs'.\n\n"
                          "Hint: a length takes one of: m, meter, meters, metre, metres, km, cm, ft, mi.")


def test_unknown_parameter_suggests_the_close_one():
    with pytest.raises(ScenarioError) as e:
        resolve_scenarios(["follower_vehicle"], {"min_scenario_duraton": "2s"})
    assert message(e) == ("overrides['min_scenario_duraton']='2s': no scenario of this run has a parameter "
                          "'min_scenario_duraton'. Did you mean 'min_scenario_duration'?\n\n"
                          "Hint: `logiq-sql scenarios` lists every parameter.")


def test_unknown_kind():
    with pytest.raises(ScenarioError) as e:
        resolve_scenarios(["follower_vehicle"], {"kinds": "vehicle,trucks"})
    assert message(e).startswith("overrides['kinds']='vehicle,trucks': 'trucks' is not an evaluation_object_kind. "
                                 "Did you mean 'truck'?")


def test_unknown_scenario():
    with pytest.raises(ScenarioError) as e:
        load_scenario("follower_vehicles")
    assert message(e) == "scenario 'follower_vehicles' not found. Did you mean 'follower_vehicle'?"


def test_inheritance_cycle(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\nextends = ["b"]\n')
    (tmp_path / "b.toml").write_text('name = "b"\nextends = ["a"]\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario("a", tmp_path)
    assert message(e) == f"{tmp_path / 'a.toml'}: inheritance cycle a -> b -> a.\n\nHint: remove one `extends` entry."


def test_unknown_key_in_a_scenario_file(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\nabstract = true\nparameters = {}\n')
    with pytest.raises(ScenarioError) as e:
        load_scenario("a", tmp_path)
    assert message(e).startswith(f"{tmp_path / 'a.toml'}: unknown key 'parameters'. Did you mean 'params'?\n\n"
                                 "Hint: the keys here are abstract, actors, coverage, description, extends, frames")


def test_parameter_with_a_bad_default(tmp_path):
    (tmp_path / "a.toml").write_text('name = "a"\nabstract = true\n[params.gap]\ntype = "length"\ndefault = "5sec"\n')
    with pytest.raises(UnitError) as e:
        load_scenario("a", tmp_path)
    assert message(e) == (f"{tmp_path / 'a.toml'} [params.gap] default: '5sec' is a time, but this parameter is a "
                          "length.\n\nHint: use a length unit such as 'm'.")


def test_parquet_missing_column(tmp_path):
    path = tmp_path / "tracks.parquet"
    pl.DataFrame({"drive_id": ["d"], "actor_id": ["a"], "kind": ["vehicle"], "t_s": [0.0], "x": [1.0],
                  "y_m": [0.0]}).write_parquet(path)
    with pytest.raises(InputError) as e:
        list(read_parquet(path))
    assert message(e) == (f"{path}: missing column 'x_m'. Did you mean 'x'?\n\n"
                          "Hint: tracks need drive_id, actor_id, kind, t_s, x_m, y_m; see docs/tables.md.")


def test_parquet_text_in_a_numeric_column(tmp_path):
    path = tmp_path / "tracks.parquet"
    pl.DataFrame({"drive_id": ["d"], "actor_id": ["a"], "kind": ["vehicle"], "t_s": [0.0], "x_m": ["1.0"],
                  "y_m": [0.0]}).write_parquet(path)
    with pytest.raises(InputError) as e:
        list(read_parquet(path))
    assert message(e) == (f"{path}: column 'x_m' is String, not a number.\n\n"
                          "Hint: write x_m as a float in the unit its name says.")


def test_cli_reports_errors_with_exit_code_2(capsys, tmp_path):
    code = main(["match", "--db", str(tmp_path / "x.duckdb"), "--set", "max_distance_from_cyclist"])
    assert code == 2
    assert capsys.readouterr().err == ("logiq-sql: error: --set max_distance_from_cyclist: write NAME=VALUE with a "
                                       "unit, e.g. --set max_distance_from_cyclist=4m.\n")
