"""The step cache (logiq_sql/storage/step_cache.py): after a change of a step's SQL, of a parameter, or of a drive's rows,
exactly the steps that depend on it run again, the rest are read from the cache, and the results are those of a
run that recomputes everything (``match --force``)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import duckdb
import pytest

from logiq_sql import LogiqError, ingest, match
from logiq_sql.cli import main
from logiq_sql.core import sql
from logiq_sql.core.sql import bind, tables_read
from logiq_sql.engines import duckdb_engine
from logiq_sql.spec.plan import parse_ego, phase_steps, resolve_scenarios, run_values
from logiq_sql.storage import step_cache
from logiq_sql.storage.step_cache import drive_column

ROOT = Path(__file__).resolve().parents[2]
NGSIM = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b"
DRIVES = [NGSIM / "USA_US101-22_1_T-1.xml.gz", NGSIM / "USA_US101-26_1_T-1.xml.gz"]
SCENARIOS = ["follower_vehicle", "sut_cut_out"]
COMPARED = {  # every output of a run, with the columns that name the run left out
    "matches": "select * exclude (run_id) from matches",
    "match_phases": "select * from match_phases",
    "kpis": "select * from kpis",
    "coverage_samples": "select * from coverage_samples",
    "coverage": "select * from coverage",
    "drive_scenarios": "select * exclude (run_id) from drive_scenarios",
    "ego_lanes": "select * from ego_lanes",
}


@pytest.fixture(autouse=True)
def keep_every_step(monkeypatch):
    # by default the cache keeps only the steps that took longer to compute than keeping them would cost, which
    # depends on the machine: here every step is kept, so which steps are reused is known
    monkeypatch.setenv("LOGIQ_SQL_STEP_CACHE", "all")


@pytest.fixture(scope="module")
def matched_once(tmp_path_factory, ingested) -> Path:
    db = ingested(tmp_path_factory.mktemp("step_cache") / "x.duckdb", "commonroad", DRIVES)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LOGIQ_SQL_STEP_CACHE", "all")
        match(db, scenarios=SCENARIOS, batch_rows=1)  # one drive per batch
    return db


def copy_with_cache(source: Path, target: Path) -> Path:
    """The file ``source`` and its step cache (the file beside it) copied to ``target``."""
    shutil.copyfile(source, target)
    shutil.copyfile(step_cache.path_of(source), step_cache.path_of(target))
    return target


def cache_of(db: Path) -> duckdb.DuckDBPyConnection:
    """The file ``db`` read-only, with its step cache attached read-only as ``cache``."""
    con = duckdb.connect(str(db), read_only=True)
    con.execute(f"attach '{step_cache.path_of(db)}' as cache (read_only)")
    return con


@pytest.fixture
def matched(tmp_path, matched_once) -> Path:
    return copy_with_cache(matched_once, tmp_path / "x.duckdb")


def assert_same_outputs(a: Path, b: Path) -> None:
    """The outputs of the two files are the same multisets of rows (EXCEPT ALL both ways)."""
    with duckdb.connect() as con:
        con.execute(f"attach '{a}' as a (read_only)")
        con.execute(f"attach '{b}' as b (read_only)")
        for table, query in COMPARED.items():
            qa, qb = query.replace(" from ", " from a."), query.replace(" from ", " from b.")
            total = con.execute(f"select count(*) from ({qa})").fetchall()[0][0]
            only_a = con.execute(f"select count(*) from ({qa} except all {qb})").fetchall()[0][0]
            only_b = con.execute(f"select count(*) from ({qb} except all {qa})").fetchall()[0][0]
            assert (only_a, only_b) == (0, 0), f"{table}: {only_a} rows only in {a.name}, {only_b} only in {b.name}"
            assert total > 0 or table == "coverage_samples", table


def forced_copy(db: Path, before: Path, **kwargs) -> Path:
    """``before`` (the file as it was before the cached run on ``db``) matched again with --force."""
    forced = copy_with_cache(before, db.with_name("forced.duckdb"))
    match(forced, force=True, **kwargs)
    return forced


def dependent_steps(scenario: str, old: dict[str, str], new: dict[str, str], scenario_path=None) -> set[str]:
    """The step labels of ``scenario``'s phase steps whose bound values differ between the overrides ``old`` and
    ``new``, and every step that reads one of them: what must run again."""
    values = []
    for overrides in (old, new):
        (s,) = resolve_scenarios([scenario], overrides, scenario_path)
        values.append(run_values(s, parse_ego("auto"), 200.0))
    changed: set[str] = set()
    out = set()
    for table, rel in [*phase_steps(s), ("scenario_matches", "match/identify.sql"),
                       ("scenario_match_phases", "match/match_phases.sql")]:
        if bind(rel, values[0]) != bind(rel, values[1]) or tables_read(rel) & changed:
            changed.add(table)
            out.add(f"{table} {rel}")
    return out


def statuses(result, scenario: str) -> dict[tuple[tuple[str, ...], str], str]:
    """(batch drives, step) -> reused or computed, for the steps run for ``scenario`` alone."""
    return {(batch, step): status for batch, owners, step, status in result.cache_steps if owners == (scenario,)}


def assert_reran(result, must_run) -> None:
    """Every cached step of ``result`` was computed when ``must_run(batch, owners, step)``, else reused; a step
    that must run may be reused from a step of the same batch with the same query file computed before it."""
    computed: set[tuple[tuple[str, ...], str]] = set()
    for batch, owners, step, status in result.cache_steps:
        query = step.split(" ", 1)[1]
        if not must_run(batch, owners, step):
            assert status == "reused", (batch, owners, step)
        elif status == "reused":
            assert (batch, query) in computed, (batch, owners, step)
        else:
            computed.add((batch, query))


@pytest.mark.parametrize("override", [{"same_road_limit": "6sec"}, {"min_scenario_duration": "3sec"}])
def test_a_parameter_change_reruns_the_steps_that_bind_it_and_those_after_them(matched, tmp_path, override):
    before = copy_with_cache(matched, tmp_path / "before.duckdb")
    result = match(matched, scenarios=SCENARIOS, overrides=override, batch_rows=1)
    assert result.up_to_date == {"follower_vehicle": 0, "sut_cut_out": 2}  # sut_cut_out has no such parameter
    rerun = dependent_steps("follower_vehicle", {}, override)
    assert rerun and (("phase_1 phases/follower_vehicle.sql" in rerun) == ("same_road_limit" in override))
    got = statuses(result, "follower_vehicle")
    assert {b for b, _ in got} == {(d,) for d in ("USA_US101-22_1_T-1@2018b", "USA_US101-26_1_T-1@2018b")}
    assert_reran(result, lambda _b, _o, step: step in rerun)
    assert got[(("USA_US101-22_1_T-1@2018b",), "relations relations/relations.sql")] == "reused"
    assert "step cache:" in result.summary() and "rows kept in" in result.summary()
    assert_same_outputs(matched, forced_copy(matched, before, scenarios=SCENARIOS, overrides=override))


def test_force_recomputes_every_step(matched):
    result = match(matched, scenarios=SCENARIOS, force=True)
    assert result.cache_steps and {status for *_, status in result.cache_steps} == {"computed"}


def own_follower(folder: Path, version: int, sql_text: str) -> Path:
    """follower_vehicle as a user's scenario (its phase query beside it), with this version and phase SQL."""
    (folder / "phases").mkdir(parents=True, exist_ok=True)
    toml = (ROOT / "scenarios/follower_vehicle.toml").read_text()
    (folder / "follower_vehicle.toml").write_text(re.sub(r"(?m)^version = \d+$", f"version = {version}", toml))
    (folder / "phases/follower_vehicle.sql").write_text(sql_text)
    sql.query_text.cache_clear()  # a new process would read the file again
    return folder


def test_a_changed_query_reruns_its_step_and_those_after_it(ingested, tmp_path):
    db = ingested(tmp_path / "x.duckdb", "commonroad", DRIVES)
    original = (ROOT / "queries/phases/follower_vehicle.sql").read_text()
    folder = own_follower(tmp_path / "mine", 1, original)
    match(db, scenarios=["follower_vehicle"], scenario_path=folder)
    before = copy_with_cache(db, tmp_path / "before.duckdb")
    # the actor counts as on the Ego's road only within half the same_road_limit: fewer or shorter matches
    changed = original.replace("+ $same_road_limit_s", "+ $same_road_limit_s / 2")
    assert changed != original
    own_follower(folder, 2, changed)
    result = match(db, scenarios=["follower_vehicle"], scenario_path=folder)
    phase = f"phase_1 {folder.resolve()}/phases/follower_vehicle.sql"
    after = {phase, "phase_frames match/phase_frames.sql#phases=1", "phase_runs match/phase_runs.sql",
             "chain match/chain.sql", "scenario_match match/sequential.sql", "scenario_matches match/identify.sql",
             "scenario_match_phases match/match_phases.sql"}
    assert phase in {step for *_, step, status in result.cache_steps if status == "computed"}
    assert_reran(result, lambda _b, _o, step: step in after)
    assert_same_outputs(db, forced_copy(db, before, scenarios=["follower_vehicle"], scenario_path=folder))
    sql.query_text.cache_clear()


def test_a_reingested_drive_drops_its_entries_and_reruns_every_step(matched, tmp_path):
    drive, other = "USA_US101-22_1_T-1@2018b", "USA_US101-26_1_T-1@2018b"
    with cache_of(matched) as con:
        had = con.execute("select count(*) from cache.step_cache where drive_id = $d", {"d": drive}).fetchall()[0][0]
        version = con.execute("select ingest_version from ingest_versions where drive_id = $d",
                              {"d": drive}).fetchall()[0][0]
    assert had > 0
    ingest("commonroad", [DRIVES[0]], matched)
    with cache_of(matched) as con:
        assert con.execute("select count(*) from cache.step_cache where drive_id = $d",
                           {"d": drive}).fetchall()[0][0] == 0
        assert con.execute("select ingest_version from ingest_versions where drive_id = $d",
                           {"d": drive}).fetchall()[0][0] != version
        for table in step_cache.cache_tables(con):
            assert con.execute(f"select count(*) from cache.{table} where {drive_column(con, table)} = $d",
                               {"d": drive}).fetchall()[0][0] == 0, table
    before = copy_with_cache(matched, tmp_path / "before.duckdb")
    override = {"same_road_limit": "6sec"}  # both drives rerun, one per batch
    result = match(matched, scenarios=SCENARIOS, overrides=override, batch_rows=1)
    rerun = dependent_steps("follower_vehicle", {}, override)
    assert_reran(result, lambda batch, owners, step: batch == (drive,)
                 or (owners == ("follower_vehicle",) and step in rerun))
    assert {o for _b, o, *_ in result.cache_steps} == {("follower_vehicle",), ("sut_cut_out",)}
    assert {b for b, *_ in result.cache_steps} == {(drive,), (other,)}
    assert_same_outputs(matched, forced_copy(matched, before, scenarios=SCENARIOS, overrides=override))


KEYED_STEPS = ("phase_frames match/phase_frames.sql#phases=1", "phase_runs match/phase_runs.sql",
               "chain match/chain.sql")  # rows that carry the drive by drive_key alone


def test_steps_keyed_by_drive_key_are_kept_per_drive_and_reused(matched, tmp_path):
    drives = ("USA_US101-22_1_T-1@2018b", "USA_US101-26_1_T-1@2018b")
    with cache_of(matched) as con:
        kept = con.execute("select step, drive_id, table_name from cache.step_cache "
                           "where scenario = 'follower_vehicle'").fetchall()
        for step in KEYED_STEPS:
            tables = {t for s, d, t in kept if s == step}
            assert {d for s, d, _ in kept if s == step} == set(drives), step
            for table in tables:  # each row beside the drive it belongs to
                assert drive_column(con, table) == "cached_drive_id", step
                assert con.execute(f"select count(*) from cache.{table} as c join drive_inputs as d on "
                                   "c.drive_key = d.drive_key and c.cached_drive_id <> d.drive_id").fetchall()[0][0] == 0
    before = copy_with_cache(matched, tmp_path / "before.duckdb")
    override = {"min_scenario_duration": "3sec"}  # read after the chains: they are reused, the match is not
    result = match(matched, scenarios=["follower_vehicle"], overrides=override, batch_rows=1)
    got = statuses(result, "follower_vehicle")
    for drive in drives:
        assert all(got[((drive,), step)] == "reused" for step in KEYED_STEPS), got
        assert got[((drive,), "scenario_match match/sequential.sql")] == "computed"
    assert not any(step.startswith("scenario_phases ") for *_, step, _s in result.cache_steps)  # reads no table
    assert_same_outputs(matched, forced_copy(matched, before, scenarios=["follower_vehicle"], overrides=override))


def test_batches_of_several_drives_read_the_entries_of_single_drive_batches(matched, tmp_path):
    before = copy_with_cache(matched, tmp_path / "before.duckdb")
    override = {"min_scenario_duration": "3sec"}
    result = match(matched, scenarios=["follower_vehicle"], overrides=override)  # both drives in one batch
    got = statuses(result, "follower_vehicle")
    assert {b for b, _ in got} == {("USA_US101-22_1_T-1@2018b", "USA_US101-26_1_T-1@2018b")}
    assert {s for (_b, s), status in got.items() if status == "reused"} >= {"phase_1 phases/follower_vehicle.sql"}
    assert_same_outputs(matched, forced_copy(matched, before, scenarios=["follower_vehicle"], overrides=override))


def test_the_cache_can_be_turned_off(matched, monkeypatch):
    monkeypatch.setenv("LOGIQ_SQL_STEP_CACHE", "off")
    result = match(matched, scenarios=["follower_vehicle"], overrides={"min_scenario_duration": "3sec"})
    assert result.cache_steps == [] and "step cache" not in result.summary()


def test_the_cache_command_reports_the_size_and_clears(matched, capsys):
    assert main(["cache", "--db", str(matched)]) == 0
    rows = int(capsys.readouterr().out.split(": ", 1)[1].split(" rows")[0].replace(",", ""))
    with cache_of(matched) as con:
        tables = step_cache.cache_tables(con)
        assert rows == sum(con.execute(f"select count(*) from cache.{t}").fetchall()[0][0] for t in tables) > 0
    assert main(["cache", "--db", str(matched), "--clear"]) == 0
    assert "0 rows in 0 table(s), 0 index entries" in capsys.readouterr().out
    result = match(matched, scenarios=["follower_vehicle"], overrides={"min_scenario_duration": "3sec"})
    assert_reran(result, lambda *_: True)  # nothing left to reuse


def test_the_cache_is_a_file_of_its_own_beside_the_file(matched, tmp_path, capsys):
    """A run's working copy of the file (storage.db.Writer) copies the file, not the cache, most of its size."""
    with duckdb.connect(str(matched), read_only=True) as con:
        assert con.execute("select count(*) from duckdb_tables() where table_name like 'step_cache%'"
                           ).fetchall()[0][0] == 0
    with cache_of(matched) as con:
        assert con.execute("select count(*) from cache.step_cache").fetchall()[0][0] > 0
        assert step_cache.cache_tables(con)
    # a file moved without its cache matches the same, from scratch
    alone = tmp_path / "alone.duckdb"
    shutil.copyfile(matched, alone)
    assert main(["cache", "--db", str(alone)]) == 0 and not step_cache.path_of(alone).exists()
    assert ": none (" in capsys.readouterr().out
    result = match(alone, scenarios=["follower_vehicle"], overrides={"min_scenario_duration": "3sec"})
    assert result.cache_steps and {status for *_, status in result.cache_steps} == {"computed"}
    assert step_cache.path_of(alone).is_file()


def test_a_file_that_kept_its_cache_inside_drops_it_when_next_written(matched):
    """Files written before the cache moved beside the file held it in tables of their own: the next writer drops
    them (nothing reads them any more)."""
    with duckdb.connect(str(matched)) as con:
        con.execute("create table step_cache (scenario varchar, step varchar)")
        con.execute("create table step_cache_0123456789abcdef01234567 as select 1 as drive_id")
    match(matched, scenarios=["follower_vehicle"], overrides={"min_scenario_duration": "3sec"})
    with duckdb.connect(str(matched), read_only=True) as con:
        assert con.execute("select count(*) from duckdb_tables() where table_name like 'step_cache%'"
                           ).fetchall()[0][0] == 0


def test_shared_and_frames_steps_are_kept_however_cheap_others_only_when_dearer_than_keeping(ingested, tmp_path,
                                                                                           monkeypatch):
    # keeping rows made to look dear (1000 CPU s per write): in the default mode no step is cheap enough to be
    # kept, except the shared ones (egos, relations, junctions), which a re-match would otherwise recompute for
    # want of their rows though every step reading them comes from the cache, and the scenario's frames step,
    # which binds no parameter and which its phases read again after any parameter change
    monkeypatch.setenv("LOGIQ_SQL_STEP_CACHE", "auto")
    monkeypatch.setattr(step_cache, "CALIBRATION_CELLS", 1)
    clock = iter(range(0, 10**9, 1000))
    monkeypatch.setattr(step_cache, "time", SimpleNamespace(process_time=lambda: float(next(clock))))
    db = ingested(tmp_path / "x.duckdb", "sumo", [ROOT / "tests/data/sumo/junction_s1"])
    result = match(db, scenarios=["unprotected_left_turn_with_yield_and_traffic_light"])
    assert "cheaper to recompute than to keep" in result.cache
    with cache_of(db) as con:
        kept = {r[0] for r in con.execute("select distinct split_part(step, ' ', 1) from cache.step_cache").fetchall()}
    shared = {"egos", "actor_lanes", "ego_lanes", "ego_road", "relations", "actor_paths", "passages",
              "junction_frames", "crossing_pairs", "encroachments", "scenario_frames"}
    assert shared <= kept, shared - kept
    assert not {"phase_1", "phase_runs", "scenario_match"} & kept, kept


def test_steps_always_kept_are_computed_straight_into_the_cache(ingested, tmp_path, monkeypatch):
    """A shared step's rows, or a frames step's, are written once, into the cache, and the batch reads them there
    (a view, as a reused step's): no temp table of them is made first. match --force, whose cache already holds
    them, computes them as temp tables. The outputs are those of a run with no cache."""
    made = []
    real = duckdb_engine.materialise

    def recorded(con, table, *args, **kwargs):
        made.append(table)
        real(con, table, *args, **kwargs)

    monkeypatch.setattr(duckdb_engine, "materialise", recorded)
    db = ingested(tmp_path / "x.duckdb", "commonroad", DRIVES)
    uncached = shutil.copyfile(db, tmp_path / "uncached.duckdb")
    result = match(db, scenarios=SCENARIOS, batch_rows=1)
    shared = {"egos", "actor_lanes", "ego_lanes", "ego_road", "relations", "scenario_frames"}  # follower's frames
    computed = {step.split(" ", 1)[0] for _, _, step, status in result.cache_steps if status == "computed"}
    assert shared <= computed, shared - computed
    assert not shared & set(made), shared & set(made)
    assert "phase_1" in made  # a step the cache may not keep is still a temp table first
    with cache_of(db) as con:
        kept = {r[0] for r in con.execute("select distinct split_part(step, ' ', 1) from cache.step_cache").fetchall()}
    assert shared <= kept, shared - kept
    made.clear()
    match(db, scenarios=SCENARIOS, force=True)
    assert shared <= set(made), shared - set(made)
    monkeypatch.setenv("LOGIQ_SQL_STEP_CACHE", "off")
    match(uncached, scenarios=SCENARIOS)
    assert_same_outputs(db, uncached)


def test_the_kept_write_part_writes_every_row_the_cache_keeps(matched, tmp_path):
    # benchmarks/components.py --kept: the rows a first match keeps, written once, are what the end-to-end target's
    # budget must hold besides the parts; each table the entries name is written whole, the relations among them
    from benchmarks.components import RELATIONS_STEP, export_kept, write_kept

    kept = export_kept(matched, tmp_path)
    with cache_of(matched) as con:
        named = [r[0] for r in con.execute("select distinct table_name from cache.step_cache").fetchall()]
        rows = {t: con.execute(f"select count(*) from cache.{t}").fetchone()[0] for t in named}
    assert {t["path"].stem: t["rows"] for t in kept} == rows
    assert [t for t in kept if RELATIONS_STEP in t["steps"]], "the relations step is not among the kept steps"
    cpu: dict[str, float] = {}
    seconds = write_kept(kept, tmp_path / "kept.duckdb", cpu)
    with duckdb.connect(str(tmp_path / "kept.duckdb"), read_only=True) as con:
        assert [con.execute(f"select count(*) from kept_{i}").fetchone()[0] for i in range(len(kept))] == [
            t["rows"] for t in kept]
    assert 0 < seconds["relations write"] < seconds["kept write"]
    assert set(cpu) == {"kept write", "relations write"}


def test_the_step_cache_option_of_a_run_overrides_the_environment(tmp_path, ingested, capsys):
    # keep_every_step sets LOGIQ_SQL_STEP_CACHE=all: --step-cache off keeps nothing beside the file, and reads nothing
    db = ingested(tmp_path / "x.duckdb", "commonroad", DRIVES[:1])
    assert main(["match", "--db", str(db), "--scenario", "follower_vehicle", "--step-cache", "off", "--quiet"]) == 0
    assert not step_cache.path_of(db).exists()
    assert "step cache" not in capsys.readouterr().out
    match(db, scenarios=["follower_vehicle"], force=True, step_cache="all")
    with cache_of(db) as con:
        assert con.execute("select count(*) from cache.step_cache").fetchone()[0] > 0
    assert main(["match", "--db", str(db), "--step-cache", "some"]) == 2
    assert "step cache mode 'some': choose one of auto, all, off" in capsys.readouterr().err
    with pytest.raises(LogiqError, match=r"step cache mode 'some': choose one of auto, all, off"):
        match(db, scenarios=["follower_vehicle"], step_cache="some")
