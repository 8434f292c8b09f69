"""Ingest's reader and checks, batch against drive by drive, in one process on the same canonical Parquet.

    python -m benchmarks.ingest_checks benchmarks/work/S/parquet      # after python -m benchmarks.tiers --tier S

Times, alternately and ``--repeat`` times each (CPU seconds of the process, all threads): reading the drives with
the Parquet reader casting each drive (``readers.parquet._drive``) and casting each chunk once
(``_drives_at_once``); then checking every drive as a batch of its own (``ingestion.clean_tracks``) and all of
them as one batch (``ingestion.clean_batch``, the same rules). Both sides must give identical drives, rows,
counts and reasons (else it stops).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import polars as pl

from logiq_sql.core.errors import InputError
from logiq_sql.core.timing import cpu_seconds
from logiq_sql.ingestion.ingest import clean_batch, clean_tracks
from logiq_sql.ingestion.readers import parquet


def _timed(fn):
    wall, cpu = time.perf_counter(), cpu_seconds()
    out = fn()
    return out, time.perf_counter() - wall, cpu_seconds() - cpu


def _read(path: Path, at_once: bool) -> list:
    real = parquet._drives_at_once
    if not at_once:
        parquet._drives_at_once = lambda *args: None  # the drive-by-drive cast
    try:
        return list(parquet.read_parquet(path))
    finally:
        parquet._drives_at_once = real


def _each(drives: list) -> dict:
    out = {}
    for i, drive in enumerate(drives):
        if drive.tracks.is_empty():
            continue
        try:
            out[i] = clean_tracks(drive)
        except InputError as exc:
            out[i] = str(exc)
    return out


def same_drives(a: list, b: list) -> None:
    """The two paths gave the same drives: every field equal, frames by value (NaN equals NaN)."""
    assert [d.drive_id for d in a] == [d.drive_id for d in b]
    for x, y in zip(a, b, strict=True):
        for name in x.__dataclass_fields__:
            u, v = getattr(x, name), getattr(y, name)
            if isinstance(u, pl.DataFrame):
                assert u.schema == v.schema and u.equals(v, null_equal=True), (x.drive_id, name)
            else:
                assert u == v or (isinstance(u, float) and math.isnan(u) and math.isnan(v)), (x.drive_id, name)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("parquet", type=Path, help="a canonical Parquet folder (tracks.parquet, drives.parquet, maps)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    for _ in range(args.repeat):
        each, w1, c1 = _timed(lambda: _read(args.parquet, False))
        drives, w2, c2 = _timed(lambda: _read(args.parquet, True))
        same_drives(drives, each)
        rows = sum(d.tracks.height for d in drives)
        print(f"read {len(drives)} drives, {rows:,} rows: per drive {c1:.2f} CPU s ({w1:.2f} s wall), "
              f"per chunk {c2:.2f} CPU s ({w2:.2f} s wall)")
        alone, w1, c1 = _timed(lambda: _each(drives))
        batch, w2, c2 = _timed(lambda: clean_batch(drives))
        for i, want in alone.items():
            got = batch[i]
            if isinstance(want, str):
                assert str(got) == want, drives[i].drive_id
                continue
            (t, n, r), (u, m, s) = got, want
            assert t.schema == u.schema and t.equals(u, null_equal=True) and (n, r) == (m, s), drives[i].drive_id
        print(f"checks: drive by drive {c1:.2f} CPU s ({w1:.2f} s wall), one batch {c2:.2f} CPU s "
              f"({w2:.2f} s wall), {len(alone)} drives")
    print("identical")


if __name__ == "__main__":
    main()
