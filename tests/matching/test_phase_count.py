"""A scenario has as many phases as its file lists: phases are rows keyed by phase_index (match/phase_frames.sql,
match/scenario_phases.sql), so a user's scenario with five phases, or one, matches with no Python or SQL change.

The drive: an actor ahead of the ego in its lane, 60 m apart at t = 0, closing at 5 m/s. Phase k holds while the
gap dx_m lies in the band (60.25 - 10 k, 70.25 - 10 k] m, that is for t in [2 (k - 1), 2 k) s less 0.05 s:
frames 20 (k - 1) .. 20 k - 1, each band 20 frames long (the quarter metre keeps a band's edges between two
frames)."""

from __future__ import annotations

from pathlib import Path

import pytest

from logiq_sql.matching.explain import explain
from logiq_sql.matching.match import match, render
from tests.helpers import Y1, actor, make_db, times

PHASE_SQL = '''-- phase: gap band {k} (the actor ahead, between {lo} m and {hi} m)
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
        coalesce(r.same_lane and r.dx_m > $band_{k}_low_m and r.dx_m <= $band_{k}_high_m, false) as in_band,
        r.dx_m
    from relations as r
)

select *, in_band as holds from conditions
'''


def band(k: int) -> tuple[float, float]:
    return 60.25 - 10 * k, 70.25 - 10 * k


def scenario_folder(tmp: Path, name: str, bands: list[int]) -> Path:
    """A user's scenario ``name`` whose phases are the gap bands ``bands``, in order, each its own query file."""
    folder = tmp / name
    folder.mkdir()
    toml = [f'name = "{name}"', 'extends = ["logiq_base_lane_following_scenario"]',
            f'description = "The actor ahead closes in through gap bands {bands}."', "version = 1", ""]
    for k in bands:
        lo, hi = band(k)
        for edge, value in (("low", lo), ("high", hi)):
            toml += [f"[params.band_{k}_{edge}]", 'type = "length"', f'default = "{value}m"',
                     f'description = "the {edge} edge of gap band {k}"', ""]
    for k in bands:
        lo, hi = band(k)
        toml += ["[[phases]]", f'name = "band_{k}"', f'query = "band_{k}.sql"',
                 f'conditions = [{{ name = "in_band", value = "dx_m", test = "in ({lo}, {hi}] m" }}]', ""]
        (folder / f"band_{k}.sql").write_text(PHASE_SQL.format(k=k, lo=lo, hi=hi))
    (folder / f"{name}.toml").write_text("\n".join(toml))
    return folder


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    t = times(10.0)
    return make_db(tmp_path_factory.mktemp("phase_count"),
                   [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("lead", t, 160 + 5 * t, Y1)])


def phases_of(result) -> list[tuple]:
    return result.match_phases.sort("phase_index").select("phase_index", "phase", "start_frame", "end_frame").rows()


def test_a_scenario_with_five_phases_matches_each_phase_in_turn(drive, tmp_path):
    folder = scenario_folder(tmp_path, "five_bands", [1, 2, 3, 4, 5])
    result = match(drive, scenarios=["five_bands"], scenario_path=folder)
    assert result.matches.select("ego_id", "actor_id", "start_frame", "end_frame").rows() == [("ego", "lead", 0, 99)]
    assert phases_of(result) == [(k, f"band_{k}", 20 * (k - 1), 20 * k - 1) for k in range(1, 6)]
    assert result.match_phases["match_id"].unique().to_list() == result.matches["match_id"].to_list()
    assert "ego ego, actor lead: 5 of 5 phases -- matched" in explain(
        drive, "five_bands", "d1", "ego", scenario_path=folder).text()
    assert "FROM phase_5" in render("five_bands", scenario_path=folder)  # the phases as rows, printed


def test_a_scenario_with_one_phase_matches_its_stretch(drive, tmp_path):
    folder = scenario_folder(tmp_path, "one_band", [3])
    result = match(drive, scenarios=["one_band"], scenario_path=folder)
    assert result.matches.select("ego_id", "actor_id", "start_frame", "end_frame").rows() == [("ego", "lead", 40, 59)]
    assert phases_of(result) == [(1, "band_3", 40, 59)]
