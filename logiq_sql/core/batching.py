"""Drives in batches of a bounded number of track rows: how ingest reads and match matches large files."""

from __future__ import annotations

from collections.abc import Iterable


def batches(sizes: Iterable[tuple[str, int]], max_rows: int) -> list[list[str]]:
    """The drive ids of ``sizes`` (drive id, rows), in order, cut into consecutive batches of at most ``max_rows``
    rows; a drive is never split, so a drive larger than ``max_rows`` is a batch of its own."""
    out: list[list[str]] = []
    filled = 0
    for drive_id, n in sizes:
        if not out or filled + n > max_rows:
            out.append([])
            filled = 0
        out[-1].append(drive_id)
        filled += n
    return out
