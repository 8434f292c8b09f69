"""``ingest FORMAT PATHS --dataset DIR``: the ordinary ingest, file by file, into a Parquet dataset (dataset.py)."""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import duckdb

from logiq_sql.ingestion.ingest import IngestSummary, expand, ingest
from logiq_sql.storage.dataset import part_name, partitions, write


def ingest_dataset(fmt: str, paths: Iterable[str | Path], folder: str | Path,
                   progress: Callable[[str], None] | None = None):
    """``ingest`` into a dataset: every input file through a temporary DuckDB file, then its tables into
    ``folder``. Returns the summary of every file together."""
    total = IngestSummary()
    with tempfile.TemporaryDirectory(prefix="logiq_sql_dataset_") as tmp:
        for i, source in enumerate(expand(fmt, paths)):
            staging = Path(tmp) / f"{i}.duckdb"
            summary = ingest(fmt, [source], staging, progress=progress)
            con = duckdb.connect(str(staging))
            try:
                clashes = _reject_clashes(con, Path(folder))
                summary.drives -= clashes
                summary.rejected += clashes
                write(con, folder, part_name(source))
            finally:
                con.close()
            staging.unlink()
            for f in dataclasses.fields(total):
                setattr(total, f.name, getattr(total, f.name) + getattr(summary, f.name))
    return total


def _reject_clashes(con: duckdb.DuckDBPyConnection, folder: Path) -> int:
    """Drives of this file whose drive_id the dataset already holds from another file: as ingest does within one
    run, the first is kept and this one is accounted for as rejected, under an id that names its file."""
    clashes = []
    for drive_id, source in con.execute("select drive_id, source_path from drive_inputs where status = 'ingested'"
                                        ).fetchall():
        earlier = [f for p in partitions(folder / "drive_inputs", "drive_id", drive_id) for f in p.glob("*.parquet")]
        if not earlier:
            continue
        (first,) = con.execute("select any_value(source_path) from read_parquet($p)",
                               {"p": [str(f) for f in earlier]}).fetchone()
        if first != source:
            clashes.append((drive_id, source, first))
    for drive_id, source, first in clashes:
        for table in ("tracks", "track_lanes", "traffic_light_states"):
            con.execute(f"delete from {table} where drive_id = $d", {"d": drive_id})
        con.execute("update drive_inputs set drive_id = $new, status = 'rejected', reject_reason = $why "
                    "where drive_id = $d",
                    {"d": drive_id, "new": f"{drive_id} ({source})",
                     "why": f"{source}: drive_id '{drive_id}' is already in the dataset, from {first}. Fix: give "
                            "every drive its own drive_id."})
    return len(clashes)
