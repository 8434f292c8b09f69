"""The DuckDB file: canonical input tables, output tables and views, with comments on every column."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql import locking, schema
from logiq_sql.errors import DiskFullError, FileBusyError, InputError, LogiqError
from logiq_sql.schema import Column, Table

S, F, I, B = pl.String(), pl.Float64(), pl.Int64(), pl.Boolean()

MATCHES = Table(
    "matches",
    "One row per match: a scenario, a drive, the ego (SUT) and the actor bound to the scenario's second role.",
    (
        Column("match_id", S, "md5 of scenario, drive, ego, actor and start frame: stable across reruns.", False),
        Column("scenario", S, "Scenario name (file in scenarios/).", False),
        Column("scenario_version", I, "The scenario file's version.", False),
        Column("params_hash", S, "Digest of the bound parameter values (see match_runs.params_json).", False),
        Column("drive_id", S, "Drive.", False),
        Column("ego_id", S, "actor_id of the ego (SUT).", False),
        Column("actor_id", S, "actor_id of the other actor (vehicle_actor, cyclist).", False),
        Column("start_frame", I, "First frame of the match.", False),
        Column("end_frame", I, "Last frame of the match (inclusive).", False),
        Column("start_s", F, "t_s of the first frame.", False),
        Column("end_s", F, "t_s of the last frame.", False),
        Column("duration_s", F, "end_s - start_s.", False),
        Column("run_id", S, "The run that produced the match: join match_runs using (run_id, scenario) for its "
                        "parameter values."),
    ),
)

MATCH_PHASES = Table(
    "match_phases",
    "The interval of every phase of every match.",
    (
        Column("match_id", S, "Match.", False),
        Column("scenario", S, "Scenario.", False),
        Column("phase_index", I, "1 for the first phase.", False),
        Column("phase", S, "Phase name from the spec.", False),
        Column("start_frame", I, "First frame of the phase.", False),
        Column("end_frame", I, "Last frame of the phase.", False),
        Column("start_s", F, "Start, seconds.", False),
        Column("end_s", F, "End, seconds.", False),
    ),
)

COVERAGE_SAMPLES = Table(
    "coverage_samples",
    "One row per (match, coverage item): the sampled value in the item's unit.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("match_id", S, "Match.", False),
        Column("item", S, "Coverage item name from the spec.", False),
        Column("unit", S, "Unit of value_num, or the enum type.", False),
        Column("value_num", F, "Numeric sample; NULL for enum items or undefined values."),
        Column("value_text", S, "Enum sample; NULL for numeric items."),
    ),
)

COVERAGE_BUCKETS = Table(
    "coverage_buckets",
    "The buckets of every coverage item: half-open [lo, hi) in the item's unit, or one enum value.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("item", S, "Coverage item.", False),
        Column("bucket_index", I, "0-based bucket number.", False),
        Column("bucket", S, "Label, e.g. '[10, 20)' or the enum value.", False),
        Column("lo", F, "Lower edge (inclusive), NULL for enum buckets."),
        Column("hi", F, "Upper edge (exclusive), NULL for enum buckets."),
        Column("value_text", S, "Enum value, NULL for numeric buckets."),
    ),
)

COVERAGE = Table(
    "coverage",
    "Coverage histograms over every match in the file: one row per bucket (empty ones too), plus 'out_of_range' "
    "and 'missing' rows where samples fell outside every bucket or were undefined.",
    (
        Column("scenario", S, "Scenario.", False),
        Column("item", S, "Coverage item.", False),
        Column("bucket_index", I, "Bucket number; NULL for out_of_range and missing."),
        Column("bucket", S, "Bucket label, 'out_of_range' or 'missing'.", False),
        Column("lo", F, "Lower edge (inclusive)."),
        Column("hi", F, "Upper edge (exclusive)."),
        Column("hits", I, "Matches whose sample fell in the bucket.", False),
    ),
)

MATCH_RUNS = Table(
    "match_runs",
    "One row per (run, scenario): the parameter values used, so every match can be rerun.",
    (
        Column("run_id", S, "Run id (time-ordered).", False),
        Column("started_at", S, "UTC start time, ISO 8601.", False),
        Column("scenario", S, "Scenario.", False),
        Column("scenario_version", I, "Scenario file version.", False),
        Column("params_hash", S, "Digest of params_json.", False),
        Column("params_json", S, "Every SQL parameter and its bound value, canonical units.", False),
        Column("overrides", S, "The --set values as written.", False),
        Column("ego_mode", S, "auto, recorded, all, every:N or an actor id.", False),
        Column("drives", I, "Drives matched in the run (drives already up to date are not rerun, see drive_scenarios).",
           False),
        Column("matches", I, "Matches found on those drives.", False),
        Column("relation_range_m", F, "The --relation-range of the run, metres."),
    ),
)

DRIVE_SCENARIOS = Table(
    "drive_scenarios",
    "One row per (drive, scenario) of the latest run of that scenario over that drive. A later run skips the pair "
    "while its run had the same params_hash, ego_mode and relation_range_m (match --force reruns it); re-ingesting "
    "the drive removes its rows.",
    (
        Column("drive_id", S, "Drive.", False),
        Column("scenario", S, "Scenario.", False),
        Column("params_hash", S, "Parameters of that run.", False),
        Column("egos", I, "SUTs considered in the drive.", False),
        Column("matches", I, "Matches found.", False),
        Column("status", S, "matched, no_match, no_ego (no actor could be the SUT) or rejected.", False),
        Column("run_id", S, "The run that matched the pair: join match_runs using (run_id, scenario)."),
    ),
)

INGEST_VERSIONS = Table(
    "ingest_versions",
    "One row per drive written by ingest: a version that changes whenever the drive's rows or its map's rows are "
    "written again. The step cache (step_cache) trusts an entry only for the version it was computed from.",
    (
        Column("drive_id", S, "Drive (drive_inputs.drive_id).", False),
        Column("ingest_version", S, "A fresh random id per ingest of the drive, or of another drive on its map.",
               False),
    ),
)

STEP_CACHE = Table(
    "step_cache",
    "The step cache's index (logiq_sql/step_cache.py): one row per (scenario, step, drive) whose step output is kept "
    "in the table step_cache_<key>. A step's key is a digest of its query text, the values it binds, the keys of "
    "the step tables it reads and the DuckDB version; an entry is read only while the drive's ingest version is "
    "the one it was computed from. Re-ingesting a drive drops its entries.",
    (
        Column("scenario", S, "A scenario whose run used the entry: each scenario keeps its latest entry per step.",
               False),
        Column("step", S, "The step table and its query file, e.g. 'phase_1 phases/ego_follows_actor.sql'.", False),
        Column("drive_id", S, "Drive.", False),
        Column("step_key", S, "Digest of the step's query text, bound values and inputs (see the table comment).",
               False),
        Column("table_name", S, "The table holding the step's rows (of every drive with this key).", False),
        Column("ingest_version", S, "ingest_versions.ingest_version of the drive when the step was computed.", False),
    ),
)

OUTPUT_TABLES = (MATCHES, MATCH_PHASES, COVERAGE_SAMPLES, COVERAGE_BUCKETS, COVERAGE, MATCH_RUNS, DRIVE_SCENARIOS)
TABLES = (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES, INGEST_VERSIONS, *OUTPUT_TABLES, STEP_CACHE)

_DUCK_TYPES = {pl.String(): "VARCHAR", pl.Float64(): "DOUBLE", pl.Int64(): "BIGINT", pl.Boolean(): "BOOLEAN"}

DRIVES_VIEW = """
create or replace view drives as
select
    d.drive_id,
    d.source_format,
    d.source_path,
    d.map_id,
    d.dt_s,
    d.ego_actor_id,
    d.rows_read,
    d.rows_rejected,
    d.reject_reason,
    case
        when d.status = 'rejected' then 'rejected'
        when count(s.scenario) = 0 then 'not_matched'
        when sum(s.matches) > 0 then 'matched'
        when bool_and(s.status = 'no_ego') then 'no_ego'
        else 'no_match'
    end as status,
    cast(coalesce(sum(s.matches), 0) as bigint) as matches,
    string_agg(s.scenario || '=' || cast(s.matches as varchar), ', ' order by s.scenario) as matches_per_scenario
from drive_inputs as d
left join drive_scenarios as s
    on d.drive_id = s.drive_id
group by
    d.drive_id, d.source_format, d.source_path, d.map_id, d.dt_s, d.ego_actor_id, d.rows_read,
    d.rows_rejected, d.reject_reason, d.status
"""
DRIVES_DOC = {
    "status": "rejected, matched (any scenario matched), no_match, no_ego, or not_matched (no run yet).",
    "matches": "Matches over every scenario run on the drive.",
    "matches_per_scenario": "scenario=count, for every scenario run on the drive.",
}


def _quote(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


def comment_column(con: duckdb.DuckDBPyConnection, table: str, column: str, doc: str) -> None:
    """Store ``doc`` as the DuckDB comment of ``table.column`` (names are ours, the text is quoted)."""
    con.execute(f"comment on column {table}.{column} is {_quote(doc)}")


def create_table(con: duckdb.DuckDBPyConnection, table: Table, extra: tuple[Column, ...] = ()) -> None:
    columns = (*table.columns, *extra)
    cols = ",\n    ".join(
        f"{c.name} {_DUCK_TYPES[c.dtype]}{'' if c.nullable else ' NOT NULL'}" for c in columns
    )
    con.execute(f"create table if not exists {table.name} (\n    {cols}\n)")
    # a file written by an earlier version gains the nullable columns added since (NULL in its old rows)
    have = {r[0] for r in con.execute(
        "select column_name from duckdb_columns() where table_name = $t and schema_name = 'main' and database_name = current_database()", {"t": table.name}).fetchall()}
    for c in columns:
        if c.name not in have and c.nullable:
            con.execute(f"alter table {table.name} add column {c.name} {_DUCK_TYPES[c.dtype]}")
    con.execute(f"comment on table {table.name} is {_quote(table.doc)}")
    for c in columns:
        con.execute(f"comment on column {table.name}.{c.name} is {_quote(c.doc)}")


# columns that mean the same in every derived table
KEY_DOCS = {
    "drive_id": "Drive.", "ego_id": "actor_id of the ego (SUT).", "actor_id": "Actor (tracks.actor_id).",
    "frame": "Sample index.", "t_s": "Time since the start of the drive, seconds.",
    "map_id": "Map.", "junction_id": "Junction.",
}


def header_docs(sql: str) -> tuple[str | None, dict[str, str]]:
    """The grain and the column descriptions of a query file's header comment: ``-- grain: ...`` and
    ``--   name[, name]   description`` lines, a description continuing on lines indented as deep."""
    grain, docs, current, indent = None, {}, [], 0
    for line in sql.splitlines():
        if not line.startswith("--"):
            break
        body = line[2:]
        if body.startswith(" grain:"):
            grain = body.split(":", 1)[1].strip()
            continue
        m = re.match(r"(\s{2,})([a-z_][a-z0-9_]*(?:,\s*[a-z_][a-z0-9_]*)*)(\s{2,})(\S.*)", body)
        if m:
            current = [name.strip() for name in m.group(2).split(",")]
            indent = len(m.group(1)) + len(m.group(2)) + len(m.group(3))
            docs.update({name: m.group(4).strip() for name in current})
        elif current and body.strip() and len(body) - len(body.lstrip()) >= indent:
            docs.update({name: docs[name] + " " + body.strip() for name in current})
        else:
            current = []
    return grain, docs


def comment_derived(con: duckdb.DuckDBPyConnection, qualified: str, name: str, doc: str,
                    column_docs: dict[str, str], fallback: str) -> None:
    """Comment a table the matcher derives (relations, ...): its columns from ``column_docs``, the shared keys,
    else ``fallback`` (where the definition is)."""
    con.execute(f"comment on table {qualified} is {_quote(doc)}")
    columns = con.execute("select column_name from duckdb_columns() where table_name = $t and schema_name = 'main' "
                          "and database_name = current_database()", {"t": name}).fetchall()
    for (col,) in columns:
        text = column_docs.get(col) or KEY_DOCS.get(col) or fallback
        con.execute(f"comment on column {qualified}.{col} is {_quote(text)}")


MEMORY_LIMIT_ENV = "LOGIQ_SQL_MEMORY_LIMIT"
# DuckDB spills to <file>.tmp beyond this instead of growing. 3 GB (2.79 GiB), with ingest's half of it
# (ingestion.INGEST_DUCKDB_SHARE), kept a 50 M-row run, Python and Polars included, at 3.80 GiB resident
# (docs/operations.md, "Memory"); at 4 GB it peaked at 5.07 GiB
DEFAULT_MEMORY_LIMIT = "3GB"


_SIZE_UNITS = {"KB": 10**3, "MB": 10**6, "GB": 10**9, "TB": 10**12,
               "KiB": 2**10, "MiB": 2**20, "GiB": 2**30, "TiB": 2**40}
_SIZE = re.compile(rf"(\d+(?:\.\d+)?)\s*({'|'.join(_SIZE_UNITS)})")


def memory_limit() -> str:
    value = os.environ.get(MEMORY_LIMIT_ENV, DEFAULT_MEMORY_LIMIT).strip()
    if not _SIZE.fullmatch(value):
        raise LogiqError(f"{MEMORY_LIMIT_ENV}={value!r}: write a size such as 4GB or 512MiB.")
    return value


def share_memory(con: duckdb.DuckDBPyConnection, fraction: float) -> None:
    """Give DuckDB only ``fraction`` of the memory limit on this connection: for a step that holds data of its own in
    Python beside DuckDB (ingest's reader), so that the two together stay within the limit's budget."""
    number, unit = _SIZE.fullmatch(memory_limit()).groups()
    con.execute("set memory_limit = $limit", {"limit": f"{int(float(number) * _SIZE_UNITS[unit] * fraction)}B"})


THREADS_ENV = "LOGIQ_SQL_THREADS"  # DuckDB worker threads; unset: DuckDB's default (the machine's cores)


def threads() -> int | None:
    value = os.environ.get(THREADS_ENV, "").strip()
    if not value:
        return None
    if not value.isdigit() or int(value) < 1:
        raise LogiqError(f"{THREADS_ENV}={value!r}: write a whole number of threads >= 1, or unset it.")
    return int(value)


def _no_progress_bar(con: duckdb.DuckDBPyConnection) -> None:
    """DuckDB's own progress bar writes into the caller's stdout; logiq_sql reports progress itself. In Jupyter
    without ipywidgets the bar is already off and turning it off raises, so only switch it off when it is on."""
    if con.execute("select current_setting('enable_progress_bar')").fetchall()[0][0]:
        con.execute("set enable_progress_bar = false")


def _config() -> dict[str, object]:
    config: dict[str, object] = {"memory_limit": memory_limit()}
    if threads() is not None:
        config["threads"] = threads()
    return config


def connect(path: str | Path, read_only: bool = False) -> duckdb.DuckDBPyConnection:
    """Open (and on first use create) a logiq_sql DuckDB file with every table and view, writing in place.

    For a file others read or write at the same time use ``open_for_write`` (a run's own copy, published when it
    completes, one writer at a time) and ``open_for_read``; ``read_only=True`` is ``open_for_read``."""
    if read_only:
        return open_for_read(path)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    con = duckdb.connect(str(path), config=_config())
    _no_progress_bar(con)
    for table in TABLES:
        create_table(con, table)
    _backfill_keys(con)
    con.execute(DRIVES_VIEW)
    con.execute("comment on view drives is " + _quote(
        "Every drive that went in, accepted or rejected, with its match status over all scenarios run."))
    inherited = {c.name: c.doc for c in schema.DRIVE_INPUTS.columns}
    for (col,) in con.execute("select column_name from duckdb_columns() where table_name = 'drives'").fetchall():
        con.execute(f"comment on column drives.{col} is {_quote(DRIVES_DOC.get(col) or inherited[col])}")
    return con


def _backfill_keys(con: duckdb.DuckDBPyConnection) -> None:
    """A file written before ingest assigned integer keys gets them for its rows (the queries join on them)."""
    drives = [r[0] for r in con.execute("select drive_id from drive_inputs where drive_key is null").fetchall()]
    if not drives:
        return
    con.register("_keys", pl.DataFrame({"drive_id": drives, "drive_key": [schema.drive_key(d) for d in drives]}))
    con.execute("update drive_inputs as d set drive_key = k.drive_key from _keys as k where d.drive_id = k.drive_id")
    con.execute("""
        update tracks as t set drive_key = k.drive_key, actor_key = k.actor_key, row_key = k.row_key
        from (
            select r.drive_id, r.actor_id, r.frame, n.drive_key,
                dense_rank() over (partition by r.drive_id order by r.actor_id) as actor_key,
                row_number() over (partition by r.drive_id order by r.actor_id, r.frame) as row_key
            from tracks as r inner join _keys as n on r.drive_id = n.drive_id
        ) as k
        where t.drive_id = k.drive_id and t.actor_id = k.actor_id and t.frame = k.frame""")
    con.execute("""
        update track_lanes as l set drive_key = t.drive_key, actor_key = t.actor_key, row_key = t.row_key
        from tracks as t
        where l.drive_key is null and l.drive_id = t.drive_id and l.actor_id = t.actor_id and l.frame = t.frame""")
    con.unregister("_keys")


def open_for_read(path: str | Path) -> duckdb.DuckDBPyConnection:
    """The file as the last completed run published it, read-only. A run never blocks this (it writes its own
    copy) and a connection keeps the state it opened until it is closed, even when a run publishes meanwhile."""
    path = Path(path)
    if not path.is_file():
        running = " (the first run writing it has not finished yet)" if _work_path(path).exists() else ""
        raise InputError(f"{path}: no such file{running}; write one with `logiq-sql ingest`.")
    con = duckdb.connect(str(path), read_only=True, config=_config())
    _no_progress_bar(con)
    return con


WORK_SUFFIX = ".writing"  # a run's own copy of the file, beside it: published over the file when the run completes


def _work_path(path: Path) -> Path:
    return Path(f"{path}{WORK_SUFFIX}")


def _stamp(path: Path) -> str:
    """One version of the file and of a WAL beside it (left by a writer killed while writing in place)."""
    parts = []
    for p in (path, Path(f"{path}.wal")):
        try:
            st = p.stat()
            parts.append(f"{st.st_ino}:{st.st_size}:{st.st_mtime_ns}")
        except FileNotFoundError:
            parts.append("-")
    return " ".join(parts)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _out_of_space(exc: BaseException | None) -> bool:
    """Whether the disk filling up caused ``exc`` (DuckDB's IOException carries the OS message)."""
    while exc is not None:
        if (isinstance(exc, OSError) and exc.errno == errno.ENOSPC) or "No space left on device" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


class Writer:
    """A run's connection to its own working copy of the file, ``<file>.writing``, holding the writer lock.

    Readers keep reading the published file meanwhile. On success the copy is checkpointed (no WAL left) and renamed
    over the file in one step (``os.replace``): a reader sees the state before the run or after it, never a part.
    A run killed before that leaves the published file as it was; its copy, consistent at its last committed
    transaction, is taken up by the next run when the file has not changed since (so committed batches are not
    redone), else discarded. A full disk stops the run, removes its copy and leaves the file as it was.
    """

    def __init__(self, path: str | Path, wait_s: float = 0.0, progress: Callable[[str], None] | None = None):
        self.path = Path(path)
        self.work = _work_path(self.path)
        self._base = Path(f"{self.work}.base")  # the stamp of the published file the copy started from
        self._lock = locking.acquire(self.path, wait_s, progress)
        self.con: duckdb.DuckDBPyConnection | None = None
        try:
            self._prepare(progress)
            self.con = connect(self.work)
        except BaseException as exc:
            self._stop(exc)
            raise

    def _prepare(self, progress: Callable[[str], None] | None) -> None:
        base = _stamp(self.path)
        if self.work.is_file() and self._base.is_file() and self._base.read_text() == base:
            if progress:
                progress(f"taking up the unpublished work of an earlier run that stopped ({self.work})")
            shutil.rmtree(f"{self.work}.tmp", ignore_errors=True)  # its spill: no use to anyone now
            return
        self._discard()
        self._base.write_text(base)
        copies = [(src, Path(f"{dst}.partial")) for src, dst in
                  ((Path(f"{self.path}.wal"), Path(f"{self.work}.wal")), (self.path, self.work)) if src.is_file()]
        for src, partial in copies:
            shutil.copyfile(src, partial)
            _fsync(partial)
        for _src, partial in copies:  # the main file last: its presence says the copy is whole
            os.replace(partial, partial.with_suffix(""))

    def _discard(self) -> None:
        for p in (self.work, Path(f"{self.work}.wal"), Path(f"{self.work}.partial"), Path(f"{self.work}.wal.partial"),
                  self._base):
            p.unlink(missing_ok=True)
        shutil.rmtree(f"{self.work}.tmp", ignore_errors=True)  # DuckDB's spill folder

    def publish(self) -> None:
        """Make the copy the file readers open, atomically; the lock is still held."""
        self.con.execute("checkpoint")
        self.con.close()
        if Path(f"{self.work}.wal").exists():
            raise RuntimeError(f"{self.work}.wal is still there after a checkpoint: not published.")
        if _stamp(self.path) != self._base.read_text():
            raise FileBusyError(
                f"{self.path} changed while this run wrote its copy, by a writer that did not take the lock "
                f"{locking.lock_path(self.path)} (e.g. logiq_sql.connect or duckdb.connect writing in place): this "
                "run was not published, so that writer's changes are not lost. Rerun it.")
        _fsync(self.work)
        stale_wal = Path(f"{self.path}.wal")
        if stale_wal.exists():  # the old file's (a writer in place was killed); its writes are in the copy
            self._base.write_text(_stamp(self.path).split(" ")[0] + " -")  # killed next: the copy is still taken up
            stale_wal.unlink()
        os.replace(self.work, self.path)
        dir_fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)  # the rename itself survives a power cut
        finally:
            os.close(dir_fd)
        self._base.unlink(missing_ok=True)

    def _stop(self, exc: BaseException | None) -> None:
        """Close the copy and free the lock; a full disk also removes the copy (and says so)."""
        try:
            if self.con is not None:
                self.con.close()
        except duckdb.Error:
            pass
        try:
            if _out_of_space(exc):
                self._discard()
                free = shutil.disk_usage(self.path.parent).free
                raise DiskFullError(
                    f"{self.path}: the disk filled up while this run wrote its copy {self.work} ({free / 1e6:,.0f} MB "
                    f"free now that the copy is removed). The run stopped; {self.path} is as the last completed run "
                    "left it. A run needs free space for a copy of the file plus what it adds (docs/operations.md, "
                    "'Disk space'): free some and rerun.") from exc
        finally:
            self._lock.release()

    def __enter__(self) -> duckdb.DuckDBPyConnection:
        return self.con

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc is None:
                self.publish()
        except BaseException as failure:
            self._stop(failure)
            raise
        self._stop(exc)


def open_for_write(path: str | Path, wait_s: float = 0.0,
                   progress: Callable[[str], None] | None = None) -> Writer | contextlib.closing:
    """``with open_for_write(path) as con:`` a run's connection, to its own copy of the file, published when the
    block completes. Waits up to ``wait_s`` seconds for another writer, else raises FileBusyError naming it.
    A named in-memory database (``:memory:NAME``, as ``match_frames`` uses) has no file to copy and no other
    process to share it with: it is written in place."""
    if str(path).startswith(":memory:"):
        return contextlib.closing(connect(path))
    return Writer(path, wait_s, progress)


def insert(con: duckdb.DuckDBPyConnection, table: str, frame: pl.DataFrame) -> None:
    """Append a Polars frame to a table by column name."""
    if frame.is_empty():
        return
    con.register("_frame_to_insert", frame)
    cols = ", ".join(frame.columns)
    con.execute(f"insert into {table} ({cols}) select {cols} from _frame_to_insert")
    con.unregister("_frame_to_insert")


def docs_markdown() -> str:
    """The tables as a markdown page (docs/tables.md is generated from this by `make docs`)."""
    out = ["# Tables in the logiq_sql DuckDB file", "",
           "Generated from `logiq_sql/schema.py` and `logiq_sql/db.py` (`make docs`). Every column also carries "
           "this text as a DuckDB comment: `select * from duckdb_columns() where comment is not null`.", ""]
    for table in (*TABLES,):
        out += [f"## `{table.name}`", "", table.doc, "", "| column | type | meaning |", "|---|---|---|"]
        out += [f"| `{c.name}` | {_DUCK_TYPES[c.dtype].lower()} | {c.doc} |" for c in table.columns]
        out.append("")
    out += ["## `kpis`", "",
            "One row per match: `match_id`, `scenario`, then every KPI and sampled coverage value of the scenarios "
            "in `scenarios/`, in the spec's units (the suffix); NULL where a scenario does not record it or the "
            "value is undefined. Columns are added as scenarios are run.", "",
            "| column | unit | meaning |", "|---|---|---|"]
    from logiq_sql.scenario import list_scenarios

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
             "file, gives the full relation of any ego on demand (`logiq_sql/relations_of.py`)."), "",
            "## `passages` and `encroachments`", "",
            "Kept from the last run of a junction scenario on each drive: every stay of an ego or related actor in a "
            "junction with its entry and exit, legs and turn (`queries/junctions/passages.sql`), and the encroachment "
            "area of every ego-actor pair whose paths through a junction cross, as WKT with the stretch of each "
            "path along which its box overlaps the area (`logiq_sql/encroachment.py`). Definitions: docs/semantics.md, unprotected_left_turn_with_yield_and_"
            "traffic_light.", "",
            "## `step_cache_<key>`", "",
            "The rows of one step of a match run, for every drive whose `step_cache` entry names the table: the "
            "columns of the step's query (`queries/...`, named in `step_cache.step`), a `drive_id` among them. "
            "`match` reads them back instead of running the step again when the step's query text, bound values "
            "and inputs and the drive's ingest version are the same (`logiq_sql/step_cache.py`; README, 'The step "
            "cache'). Rows no entry refers to are deleted, a table with none dropped; `logiq-sql cache --db FILE` "
            "gives their size, `--clear` drops them all.", "",
            "## `drives` (view)", "",
            "Every drive of `drive_inputs` with its status over all scenarios run: " + DRIVES_DOC["status"], ""]
    return "\n".join(out)
