"""Wall time and peak memory of the pipeline's stages, recorded only while a benchmark listens.

``with stage("localisation"):`` costs one global read when nobody records; inside ``recording()`` every stage
adds its wall seconds (summed over calls), the CPU seconds of the whole process meanwhile (every thread: DuckDB's,
shapely's; steadier than wall time on a shared machine) and the highest resident memory seen while it ran
(sampled every 20 ms by a background thread, so DuckDB's and shapely's native memory count too).
"""

from __future__ import annotations

import os
import resource
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Resident memory of this process now (Linux /proc), else the peak so far."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def cpu_seconds() -> float:
    """User and system CPU time of this process so far, all threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@dataclass
class Stages:
    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)
    peak_rss_bytes: dict[str, int] = field(default_factory=dict)
    calls: dict[str, int] = field(default_factory=dict)
    _open: set[str] = field(default_factory=set)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def _seen(self, rss: int) -> None:
        with self._lock:
            for name in self._open:
                self.peak_rss_bytes[name] = max(self.peak_rss_bytes.get(name, 0), rss)


_current: Stages | None = None


@contextmanager
def stage(name: str) -> Iterator[None]:
    rec = _current
    if rec is None:
        yield
        return
    with rec._lock:
        rec._open.add(name)
    rec._seen(rss_bytes())
    start, cpu_start = time.perf_counter(), cpu_seconds()
    try:
        yield
    finally:
        elapsed, cpu = time.perf_counter() - start, cpu_seconds() - cpu_start
        rec._seen(rss_bytes())
        with rec._lock:
            rec._open.discard(name)
            rec.seconds[name] = rec.seconds.get(name, 0.0) + elapsed
            rec.cpu_seconds[name] = rec.cpu_seconds.get(name, 0.0) + cpu
            rec.calls[name] = rec.calls.get(name, 0) + 1


@contextmanager
def recording(interval_s: float = 0.02) -> Iterator[Stages]:
    """Record every stage run inside the block (one recorder at a time)."""
    global _current
    rec = Stages()
    done = threading.Event()

    def sample() -> None:
        while not done.wait(interval_s):
            rec._seen(rss_bytes())

    sampler = threading.Thread(target=sample, daemon=True)
    _current = rec
    sampler.start()
    try:
        yield rec
    finally:
        done.set()
        sampler.join()
        _current = None
