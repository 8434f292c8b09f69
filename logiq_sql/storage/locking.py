"""One writer at a time per DuckDB file: an OS lock on ``<file>.lock`` beside it.

The lock is ``flock`` on an open file: the kernel drops it when the holder closes it, exits or is killed, so a
killed run never leaves a stale lock. The holder writes who it is (pid, command, host, since when) into the lock
file, so that a second writer can name it. (``flock`` may not work across machines on a network file system.)
"""

from __future__ import annotations

import datetime as dt
import fcntl
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

from logiq_sql.core.errors import FileBusyError, arg

LOCK_SUFFIX = ".lock"
SAY_EVERY_S = 10.0  # a waiting writer prints one progress line this often
POLL_S = 0.2


def lock_path(db_path: str | Path) -> Path:
    return Path(str(db_path) + LOCK_SUFFIX)


def holder(db_path: str | Path) -> str:
    """Who holds the writer lock of ``db_path``, as its holder wrote it: 'pid 12 (logiq-sql match ...) on host
    since 2026-01-01T02:00:00Z'."""
    try:
        info = json.loads(lock_path(db_path).read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    if not info:
        return "a process that has not yet written its name into the lock file"
    return f"pid {info.get('pid')} ({info.get('command')}) on {info.get('host')} since {info.get('since')}"


class WriterLock:
    """The held lock; ``release`` (or the end of the process) frees it."""

    def __init__(self, db_path: Path, fd: int):
        self.db_path, self._fd = db_path, fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the file drops the flock
            self._fd = None


def acquire(db_path: str | Path, wait_s: float = 0.0, progress: Callable[[str], None] | None = None) -> WriterLock:
    """Take the writer lock of ``db_path``, waiting up to ``wait_s`` seconds for another writer (a progress line
    every SAY_EVERY_S); raise FileBusyError naming the holder when it is still held."""
    db_path = Path(db_path)
    path = lock_path(db_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    start = time.monotonic()
    said = None
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            waited = time.monotonic() - start
            if waited >= wait_s:
                os.close(fd)
                raise FileBusyError(
                    f"{db_path}: another run is writing it: {holder(db_path)}. Readers are not affected. Wait for "
                    f"it with {arg('wait_s', 60)} (seconds){f' (waited {waited:.0f} s)' if wait_s else ''}, or stop that process "
                    "if it should not run.") from None
            if progress and (said is None or waited - said >= SAY_EVERY_S):
                progress(f"waiting for {holder(db_path)} to finish writing {db_path} "
                         f"({waited:.0f} of {wait_s:g} s)")
                said = waited
            time.sleep(min(POLL_S, max(wait_s - waited, 0.0)))
    info = {"pid": os.getpid(), "command": shlex.join(sys.orig_argv)[:300], "host": socket.gethostname(),
            "since": dt.datetime.now(dt.UTC).isoformat(timespec="seconds").replace("+00:00", "Z")}
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(info).encode(), 0)
    return WriterLock(db_path, fd)
