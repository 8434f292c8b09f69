"""Issue 16: a scheduled run and analysts at the same time (docs/operations.md, "Scheduled runs" and "Disk space").

Readers open the published file read-only while a run writes its own copy; one writer at a time (a second one
waits or stops with exit 4); a killed or failed run leaves the published state as it was."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import duckdb
import polars as pl
import pytest

from logiq_sql.cli import EXIT_BUSY, EXIT_DISK_FULL
from logiq_sql.core import schema
from logiq_sql.storage import locking

ROOT = Path(__file__).resolve().parents[2]
NGSIM = ROOT / "tests/data/commonroad_ngsim/scenarios_2018b"
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "LOGIQ_SQL_THREADS": "1"}
CLI = [sys.executable, "-m", "logiq_sql.cli"]
SEED_SCENES = sorted(NGSIM.glob("USA_US101-*.xml.gz"), key=lambda p: p.stat().st_size)[:8]  # the 8 smallest
FIRST_COPIES, LATER_COPIES = range(0, 5), range(5, 30)  # 40 drives, then 200 more
READERS = 8

# one statement, so one snapshot: what a published state holds, and whether its tables agree with one another
CHECK = """
select
    (select count(*) from drive_inputs) as drives,
    (select count(*) from drive_inputs where status = 'ingested') as ingested,
    (select count(distinct drive_id) from tracks) as drives_with_tracks,
    (select count(*) from tracks) as tracks,
    (select coalesce(sum(rows_read - rows_rejected), 0) from drive_inputs) as tracks_expected,
    (select count(*) from matches) as matches,
    (select coalesce(sum(matches), 0) from drive_scenarios) as matches_expected,
    (select count(*) from drive_scenarios) as drive_scenarios
"""

# a reader process: opens the published file, runs CHECK, closes, again and again until told to stop
READER = """
import json, os, sys, time
from logiq_sql.storage.db import open_for_read
db, check, stop, out = sys.argv[1:]
os.nice(10)  # on 2 cores, 8 readers at the runs' priority starve them (ingest: 10 s alone, 154 s beside them)
with open(out, "w") as f:
    while not os.path.exists(stop):
        start = time.time()
        try:
            with open_for_read(db) as con:
                answer = list(con.execute(check).fetchall()[0])
        except Exception as exc:
            answer = f"{type(exc).__name__}: {exc}"
        f.write(json.dumps([start, time.time() - start, answer]) + "\\n")
        f.flush()
        time.sleep(0.05)
"""


def consistent(state: list[int]) -> bool:
    drives, ingested, with_tracks, tracks, tracks_expected, matches, matches_expected, _ = state
    return with_tracks == ingested <= drives and tracks == tracks_expected and matches == matches_expected


def check(db: Path) -> list[int]:
    with duckdb.connect(str(db), read_only=True) as con:
        return list(con.execute(CHECK).fetchall()[0])


def cpu_s(proc: subprocess.Popen) -> float:
    """Wait for a child and return the CPU seconds it used (user + system)."""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_utime + usage.ru_stime


def run(args: list[str], kill_after: str | None = None, cpu: list[float] | None = None) -> tuple[int, str]:
    """A logiq-sql command; with ``kill_after``, SIGKILLed as soon as a progress line holds that text. Its CPU
    seconds are appended to ``cpu``."""
    proc = subprocess.Popen([*CLI, *args], cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if kill_after is not None and kill_after in line:
            proc.send_signal(signal.SIGKILL)
            break
    used = cpu_s(proc)
    if cpu is not None:
        cpu.append(used)
    proc.stderr.close()
    return proc.returncode, "".join(seen)


@pytest.fixture(scope="module")
def parquet_drives(tmp_path_factory) -> tuple[Path, Path]:
    """The bundled scenes replicated as canonical Parquet: copy k of a drive is ``<drive_id>~k`` (maps shared),
    its first vehicle by actor id the recorded ego. Two folders: a first ingest and a later, larger one."""
    tmp = tmp_path_factory.mktemp("drives")
    seed = tmp / "seed.duckdb"
    assert run(["ingest", "commonroad", *map(str, SEED_SCENES), "--db", str(seed), "--quiet"])[0] == 0
    with duckdb.connect(str(seed), read_only=True) as con:
        drives = con.sql("select drive_id, dt_s, map_id from drive_inputs").pl()
        tracks = con.sql("select drive_id, actor_id, kind, frame, t_s, x_m, y_m, heading_rad, speed_mps, length_m, "
                         "width_m, actor_id = min(case when kind = 'vehicle' then actor_id end) over "
                         "(partition by drive_id) as is_ego from tracks").pl()
        maps = {t: con.sql(f"select * from {t}").pl() for t in schema.MAP_TABLE_NAMES}
    folders = []
    for name, copies in (("first", FIRST_COPIES), ("later", LATER_COPIES)):
        folder = tmp / name
        folder.mkdir()
        for table, frame in (("tracks", tracks), ("drives", drives)):
            pl.concat([frame.with_columns(pl.col("drive_id") + f"~{k}") for k in copies]).write_parquet(
                folder / f"{table}.parquet")
        for table, frame in maps.items():
            frame.write_parquet(folder / f"{table}.parquet")
        folders.append(folder)
    return folders[0], folders[1]


def answered(path: Path) -> list[list]:
    """A reader's answers so far: [start time, seconds, the CHECK row or the error]."""
    return [json.loads(line) for line in path.read_text().split("\n")[:-1]] if path.exists() else []  # whole lines


class DiskWatch:
    """Polls the bytes of the published file and of what a run keeps beside it (its copy, WAL, spill folder):
    the peak of their sum, and the published file's size then."""

    def __init__(self, db: Path):
        self.db, self.peak, self.published_then = db, 0, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _poll(self) -> None:
        while not self._stop.wait(0.05):
            beside = 0
            for p in self.db.parent.glob(self.db.name + ".*"):
                try:
                    beside += sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() \
                        else p.stat().st_size
                except FileNotFoundError:  # renamed or removed while counted
                    pass
            try:
                published = self.db.stat().st_size
            except FileNotFoundError:
                continue
            if published + beside > self.peak:
                self.peak, self.published_then = published + beside, published

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


@pytest.mark.load
def test_readers_see_only_published_states_while_runs_write_and_after_one_is_killed(tmp_path, parquet_drives):
    first, later = parquet_drives
    db = tmp_path / "x.duckdb"
    assert run(["ingest", "parquet", str(first), "--db", str(db), "--quiet"])[0] == 0
    published = [check(db)]
    stop = tmp_path / "stop"
    readers = [subprocess.Popen([sys.executable, "-c", READER, str(db), CHECK, str(stop), str(tmp_path / f"r{i}")],
                                cwd=ROOT, env=ENV) for i in range(READERS)]
    watch = DiskWatch(db)
    started = time.time()
    cpu: list[float] = []  # the runs' CPU seconds, to tell what a dedicated machine would take
    try:
        assert run(["ingest", "parquet", str(later), "--db", str(db), "--quiet"], cpu=cpu)[0] == 0
        published.append(check(db))
        ingested = time.time()
        code, progress = run(["match", "--db", str(db), "--ego", "recorded", "--scenario", "follower_vehicle",
                              "--scenario", "sut_cut_out"], cpu=cpu)
        assert code == 0, progress
        published.append(check(db))
        matched = time.time()
        # a run with another parameter would replace every follower match: killed once its relations are made
        code, _ = run(["match", "--db", str(db), "--ego", "recorded", "--scenario", "follower_vehicle",
                       "--set", "min_scenario_duration=2s"], kill_after="relations:", cpu=cpu)
        assert code == -signal.SIGKILL
        killed = time.time()
        while not all(any(a[0] > killed for a in answered(tmp_path / f"r{i}")) for i in range(READERS)):
            assert time.time() < killed + 120, "a reader did not query after the kill"
            time.sleep(0.2)  # the readers go on after the kill
        went_on = time.time()
    finally:
        watch.stop()
        stop.touch()
        reader_cpu = sum(cpu_s(r) for r in readers)
    assert check(db) == published[-1]  # the killed run published nothing
    answers = [a for i in range(READERS) for a in answered(tmp_path / f"r{i}")]
    failed = [a for a in answers if isinstance(a[2], str)]
    assert not failed, failed[:3]
    assert all(consistent(state) for state in published)
    assert published[0][0] == 40 and published[1][0] == 240 and published[2][5] > 0  # three different states
    states = {tuple(a[2]) for a in answers}
    assert states <= {tuple(s) for s in published}  # every answer is a state some run published
    assert {tuple(published[0]), tuple(published[-1])} <= states  # the readers saw the runs publish
    after_kill = [a for a in answers if a[0] > killed]
    assert {tuple(a[2]) for a in after_kill} == {tuple(published[-1])}
    waits = sorted(a[1] for a in answers)
    final = db.stat().st_size
    print(f"\nRuns: ingest of 200 drives {ingested - started:.1f} s, match {matched - ingested:.1f} s, killed match "
          f"{killed - matched:.1f} s, then {went_on - killed:.1f} s until every reader had queried again. "
          f"{len(answers)} reader queries ({READERS} processes at nice 10, each opening the file, running one "
          f"statement and closing it) in {went_on - started:.1f} s: {len(answers) / (went_on - started):.1f} "
          f"queries/s; time per query (open, query, close): median "
          f"{waits[len(waits) // 2] * 1000:.0f} ms, longest {waits[-1] * 1000:.0f} ms; states seen: {len(states)}. "
          f"CPU: the runs {' + '.join(f'{c:.1f}' for c in cpu)} s, the readers {reader_cpu:.1f} s; load average "
          f"{os.getloadavg()[0]:.1f}."
          f"\nDisk: peak {watch.peak / 1e6:.1f} MB (published file {watch.published_then / 1e6:.1f} MB then, its copy, "
          f"WAL and spill the rest); the final file is {final / 1e6:.1f} MB: peak = {watch.peak / final:.2f}x it.")


def hold_lock(db: Path) -> subprocess.Popen:
    """Another writer: a process that takes the writer lock of ``db`` and keeps it until killed."""
    code = ("import sys, time; from logiq_sql.storage import locking; locking.acquire(sys.argv[1]); print('held', "
            "flush=True); time.sleep(600)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(db)], cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_stops_at_once_naming_the_other_or_waits_for_it(tmp_path):
    db = tmp_path / "x.duckdb"
    scene = str(SEED_SCENES[0])
    assert run(["ingest", "commonroad", scene, "--db", str(db), "--quiet"])[0] == 0
    before = check(db)
    other = hold_lock(db)
    try:
        run_ = subprocess.run([*CLI, "match", "--db", str(db), "--quiet"], cwd=ROOT, env=ENV, capture_output=True,
                              text=True)
        assert run_.returncode == EXIT_BUSY
        assert f"{db}: another run is writing it: pid {other.pid} (" in run_.stderr
        assert "locking.acquire" in run_.stderr and " since 20" in run_.stderr and "--wait" in run_.stderr
        assert "Traceback" not in run_.stderr
        assert check(db) == before  # readers are not blocked by it either
        read = subprocess.run([*CLI, "query", "select count(*) from drives", "--db", str(db)], cwd=ROOT, env=ENV,
                              capture_output=True, text=True)
        assert read.returncode == 0, read.stderr
        # --wait: progress while waiting, then the run once the other writer is gone (killed: no stale lock)
        waiting = subprocess.Popen([*CLI, "match", "--db", str(db), "--scenario", "follower_vehicle", "--wait", "60"],
                                   cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = waiting.stderr.readline()
        assert first.startswith(f"waiting for pid {other.pid} (") and f"to finish writing {db}" in first
        other.kill()
        out, err = waiting.communicate(timeout=300)
        assert waiting.returncode == 0, err
        assert check(db)[5] > 0
        other = hold_lock(db)  # the report too reads while a run writes
        report = subprocess.run([*CLI, "report", "--db", str(db), "--out", str(tmp_path / "r.html")], cwd=ROOT,
                                env=ENV, capture_output=True, text=True)
        assert report.returncode == 0, report.stderr
    finally:
        other.kill()
        other.wait()


def test_a_writer_that_waits_too_long_gives_up_with_exit_4(tmp_path, capsys):
    from logiq_sql.cli import main

    db = tmp_path / "x.duckdb"
    other = hold_lock(db)
    try:
        assert main(["ingest", "commonroad", str(SEED_SCENES[0]), "--db", str(db), "--wait", "0.5"]) == EXIT_BUSY
        err = capsys.readouterr().err
        assert err.startswith(f"waiting for pid {other.pid}")
        assert f"another run is writing it: pid {other.pid}" in err and "(waited " in err
        assert not db.exists() and not db.with_name("x.duckdb.writing").exists()
    finally:
        other.kill()
        other.wait()
    locking.acquire(db).release()  # the killed holder left no stale lock


def test_a_run_failing_after_commits_publishes_nothing_and_the_next_run_takes_its_work_up(tmp_path):
    from logiq_sql import ingest

    db = tmp_path / "x.duckdb"
    ingest("commonroad", SEED_SCENES[:1], db)
    before = check(db)

    class Stop(Exception):
        pass

    def stop_after_second(line: str) -> None:  # after the second file's batch is committed
        if line.startswith("[2/"):
            raise Stop
    import logiq_sql.ingestion.ingest as ingestion
    keep, ingestion.BATCH_ROWS = ingestion.BATCH_ROWS, 1  # one transaction per drive
    try:
        with pytest.raises(Stop):
            ingest("commonroad", SEED_SCENES[1:4], db, progress=stop_after_second)
        assert check(db) == before
        work = db.with_name("x.duckdb.writing")
        assert check(work)[0] == 3  # the first drive, and the two committed before the failure
        lines = []
        ingest("commonroad", SEED_SCENES[1:4], db, progress=lines.append)
    finally:
        ingestion.BATCH_ROWS = keep
    assert lines[0].startswith("taking up the unpublished work of an earlier run")
    assert check(db)[0] == 4 and consistent(check(db)) and not work.exists()


@pytest.fixture
def small_disk(tmp_path):
    """A 6 MB tmpfs (needs root, as in CI's container); skipped where mounting is not allowed."""
    mount = tmp_path / "disk"
    mount.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=6m", "tmpfs", str(mount)], capture_output=True)
    if made.returncode:
        pytest.skip(f"cannot mount a small tmpfs here: {made.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", str(mount)], check=True)


def test_a_full_disk_stops_the_run_with_exit_5_and_leaves_the_published_file(small_disk):
    db = small_disk / "x.duckdb"
    assert run(["ingest", "commonroad", str(SEED_SCENES[0]), "--db", str(db), "--quiet"])[0] == 0
    before, size = check(db), db.stat().st_size
    # more drives than the disk holds beside the file and its copy
    many = sorted(NGSIM.glob("USA_US101-*.xml.gz"))
    run_ = subprocess.run([*CLI, "ingest", "commonroad", *map(str, many), "--db", str(db), "--quiet"], cwd=ROOT,
                          env=ENV, capture_output=True, text=True)
    assert run_.returncode == EXIT_DISK_FULL, run_.stderr
    assert f"logiq-sql: disk full: {db}: the disk filled up while this run wrote its copy" in run_.stderr
    assert "Traceback" not in run_.stderr
    assert check(db) == before and db.stat().st_size == size
    assert sorted(p.name for p in small_disk.iterdir()) == ["x.duckdb", "x.duckdb.lock"]  # the copy is gone
    assert run(["ingest", "commonroad", str(SEED_SCENES[1]), "--db", str(db), "--quiet"])[0] == 0  # room again
    assert check(db)[0] == 2


# a reader of the publish race test: each answer must be a whole publish, and never older than the one before
RACE_READER = """
import os, sys
from logiq_sql.storage.db import open_for_read
db, stop, out = sys.argv[1:]
seen, errors = [], []
while not os.path.exists(stop):
    try:
        with open_for_read(db) as con:
            seen.append(con.execute("select (select count(*) from runs), (select max(n) from runs)").fetchall()[0])
    except Exception as exc:
        errors.append(f"{type(exc).__name__}: {exc}")
with open(out, "w") as f:
    f.write(repr((seen, errors)))
"""


@pytest.mark.load
def test_readers_opening_while_runs_publish_one_after_another_never_fail_or_go_back(tmp_path):
    from logiq_sql.storage import db as logiq_db

    path = tmp_path / "x.duckdb"
    with logiq_db.open_for_write(path) as con:
        con.execute("create table runs (n bigint)")
    stop = tmp_path / "stop"
    readers = [subprocess.Popen([sys.executable, "-c", RACE_READER, str(path), str(stop), str(tmp_path / f"r{i}")],
                                cwd=ROOT, env=ENV) for i in range(4)]
    try:
        for n in range(1, 26):  # 25 runs, each adding one row and publishing
            with logiq_db.open_for_write(path) as con:
                con.execute("insert into runs values ($n)", {"n": n})
    finally:
        stop.touch()
        for r in readers:
            r.wait(timeout=120)
    import ast

    results = [ast.literal_eval((tmp_path / f"r{i}").read_text()) for i in range(4)]
    assert [errors for _, errors in results] == [[]] * 4
    for seen, _ in results:
        assert seen and all(count == (last or 0) for count, last in seen)  # whole runs only
        assert [count for count, _ in seen] == sorted(count for count, _ in seen)  # never an older state
    print(f"\n25 publishes; reader opens: {sum(len(seen) for seen, _ in results)}, none failed")


def test_a_leftover_copy_of_another_version_of_the_file_is_discarded_not_published(tmp_path):
    from logiq_sql import ingest

    db = tmp_path / "x.duckdb"
    ingest("commonroad", SEED_SCENES[:1], db)
    # a copy left by a run killed while copying, and its stamp from a file that has changed since
    work = db.with_name("x.duckdb.writing")
    work.write_bytes(b"not a database")
    work.with_name("x.duckdb.writing.base").write_text("1:2:3 -")
    work.with_name("x.duckdb.writing.partial").write_bytes(b"half")
    lines = []
    ingest("commonroad", SEED_SCENES[1:2], db, progress=lines.append)
    assert not any("taking up" in line for line in lines)
    assert check(db)[0] == 2 and consistent(check(db))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.duckdb", "x.duckdb.lock"]


def test_a_run_does_not_publish_over_a_file_written_in_place_meanwhile(tmp_path):
    from logiq_sql.core.errors import FileBusyError
    from logiq_sql.storage import db as logiq_db

    path = tmp_path / "x.duckdb"
    with logiq_db.open_for_write(path) as con:
        con.execute("create table notes (text varchar)")
    with pytest.raises(FileBusyError, match="changed while this run wrote its copy"):
        with logiq_db.open_for_write(path) as con:
            con.execute("insert into notes values ('from the run')")
            with duckdb.connect(str(path)) as in_place:  # a writer that takes no lock
                in_place.execute("insert into notes values ('in place')")
    with logiq_db.open_for_read(path) as con:
        assert con.execute("select text from notes").fetchall() == [("in place",)]


def test_a_wal_left_by_a_writer_in_place_is_taken_into_the_copy_and_not_left_beside_the_new_file(tmp_path):
    from logiq_sql.storage import db as logiq_db

    path = tmp_path / "x.duckdb"
    with logiq_db.open_for_write(path) as con:
        con.execute("create table notes (text varchar)")
    # a writer in place (an older logiq_sql, or duckdb.connect) killed after a commit that is only in its WAL
    code = ("import duckdb, os, sys; con = duckdb.connect(sys.argv[1]); con.execute(\"set checkpoint_threshold = '1GB'\"); "
            "con.execute(\"insert into notes values ('in the wal')\"); os._exit(0)")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True)
    assert path.with_name("x.duckdb.wal").exists()
    with logiq_db.open_for_write(path) as con:
        con.execute("insert into notes values ('from the run')")
    assert not path.with_name("x.duckdb.wal").exists()
    with logiq_db.open_for_read(path) as con:
        assert sorted(con.execute("select text from notes").fetchall()) == [("from the run",), ("in the wal",)]
