"""The DuckDB file's connections: DuckDB's settings from the environment, opening a file, and the publish protocol
(a run writes its own copy and publishes it atomically, one writer at a time, readers never blocked)."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import duckdb

from logiq_sql.core.errors import DiskFullError, FileBusyError, InputError, LogiqError
from logiq_sql.storage import locking, step_cache, tables

MEMORY_LIMIT_ENV = "LOGIQ_SQL_MEMORY_LIMIT"
# DuckDB spills to <file>.tmp beyond this instead of growing. With ingest's half of it
# (ingestion.INGEST_DUCKDB_SHARE) a tier-L run, Python and Polars included, stays within the 4 GiB bound, which
# a limit of 4GB did not (docs/operations.md, "Memory"; the figures in benchmarks/README.md)
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
    tables.create_all(con)
    return con


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


def open_current(path: str | Path) -> duckdb.DuckDBPyConnection:
    """``open_for_read``, refusing with the fix a file written by an earlier logiq_sql that no run has opened for
    writing since (``tables.require_current``): reports, replays, exports and explain read the columns added since,
    which a read-only connection cannot add."""
    con = open_for_read(path)
    try:
        tables.require_current(con, path)
    except BaseException:
        con.close()
        raise
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
    The step cache is not in the copy: it is a file of its own beside the file, which only the lock's holder opens,
    attached to the connection as ``cache`` and written in place (logiq_sql/storage/step_cache.py).
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
            step_cache.attach(self.con, self.path, create=False)  # made by the first match that keeps steps
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


def stored_schema(con: duckdb.DuckDBPyConnection) -> str:
    """The DuckDB file's own schema, quoted: names in it stay reachable while a temp table shadows them."""
    return '"' + con.execute("select current_database()").fetchall()[0][0].replace('"', '""') + '".main'
