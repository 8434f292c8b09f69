"""Ingest: read drives from a source format into the canonical tables of a DuckDB file.

Every file that goes in is accounted for in ``drive_inputs``: ingested (possibly with some rows rejected) or
rejected with the reason. Re-ingesting a drive replaces it (same drive_id), so ingest is idempotent.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql import db, schema
from logiq_sql.errors import InputError, LogiqError, did_you_mean
from logiq_sql.localise import locate
from logiq_sql.readers.av2 import log_folders
from logiq_sql.readers.base import DriveData
from logiq_sql.readers.sumo import run_folders
from logiq_sql.sql import query_text
from logiq_sql.timing import stage

FORMATS = ("commonroad", "scenarionet", "parquet", "sumo", "av2")


_SUFFIXES = {"commonroad": (".xml", ".xml.gz"), "scenarionet": (".pkl",), "parquet": (".parquet",)}


def _reader(fmt: str) -> Callable[[Path], Iterable[DriveData]]:
    module = importlib.import_module(f"logiq_sql.readers.{fmt}")
    return getattr(module, f"read_{fmt}")


@dataclass
class IngestSummary:
    drives: int = 0
    rejected: int = 0
    rows: int = 0
    rows_rejected: int = 0

    def __str__(self) -> str:
        return (f"{self.drives} drive(s) ingested, {self.rejected} rejected; "
                f"{self.rows:,} track rows, {self.rows_rejected:,} rows rejected")


def expand(fmt: str, paths: Iterable[str | Path]) -> list[Path]:
    """Files to read: each path as given, or the matching files inside a folder (sorted); for sumo, run folders;
    for av2, log and scenario folders."""
    out: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise InputError(f"{p}: no such file or folder.")
        if fmt == "sumo":
            out += run_folders(p)
        elif fmt == "av2":
            out += log_folders(p)
        elif p.is_dir() and not (fmt == "parquet" and (p / "tracks.parquet").exists()):
            out += sorted(f for f in p.rglob("*") if f.is_file() and f.name.endswith(_SUFFIXES[fmt]))
        else:
            out.append(p)
    return out


BATCH_ROWS = 1_000_000  # drives are written in batches of about this many track rows (bounded memory)


def ingest(fmt: str, paths: Iterable[str | Path], db_path: str | Path,
           progress: Callable[[str], None] | None = None) -> IngestSummary:
    """Read every file of ``paths`` with the ``fmt`` reader into the DuckDB file ``db_path``."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format '{fmt}'.{did_you_mean(fmt, FORMATS)} Formats: {', '.join(FORMATS)}.")
    reader = _reader(fmt)
    files = expand(fmt, paths)
    con = db.connect(db_path)
    summary = IngestSummary()
    batch: list[DriveData] = []
    batch_rows = 0
    try:
        for i, path in enumerate(files, 1):
            count = 0
            try:
                for drive in reader(path):  # readers may stream: drives are written as batches fill up
                    batch.append(drive)
                    batch_rows += drive.tracks.height
                    count += 1
                    if batch_rows >= BATCH_ROWS:
                        _count(summary, write_drives(con, batch))
                        batch, batch_rows = [], 0
            except LogiqError as exc:
                # the file could not be read: one rejected drive named after it
                _reject(con, DriveData(path.name.split(".")[0], fmt, str(path), math.nan, pl.DataFrame()), str(exc))
                summary.rejected += 1
                if progress:
                    progress(f"[{i}/{len(files)}] {path.name}: rejected: {exc}")
                continue
            if progress:
                progress(f"[{i}/{len(files)}] {path.name}: {count} drive(s)")
        _count(summary, write_drives(con, batch))
    finally:
        con.close()
    return summary


def _count(summary: IngestSummary, written: list[tuple[DriveData, int]]) -> None:
    for drive, kept in written:
        if kept:
            summary.drives += 1
            summary.rows += kept
            summary.rows_rejected += (drive.rows_read or kept) - kept
        else:
            summary.rejected += 1


def clean_tracks(drive: DriveData) -> tuple[pl.DataFrame, int, list[str]]:
    """Check a reader's rows: kinds known, values finite, one row per (actor, frame), sizes filled.

    Returns the kept rows, how many were dropped and the reasons.
    """
    tracks = drive.tracks
    missing = [c for c in ("drive_id", "actor_id", "kind", "frame", "t_s", "x_m", "y_m") if c not in tracks.columns]
    if missing:
        raise InputError(f"{drive.source_path}: tracks lack column(s) {', '.join(missing)}.")
    bad_kinds = sorted(set(tracks["kind"].unique().to_list()) - set(schema.OBJECT_KINDS) - {None})
    if bad_kinds:
        raise InputError(
            f"{drive.source_path}: column 'kind' has unknown value(s) {', '.join(map(repr, bad_kinds))}."
            f"{did_you_mean(str(bad_kinds[0]), schema.OBJECT_KINDS)}\n\n"
            f"Hint: kinds are the spec's evaluation_object_kind values: {', '.join(schema.OBJECT_KINDS)}."
        )
    reasons: list[str] = []
    finite = pl.all_horizontal(
        pl.col(c).is_not_null() & pl.col(c).is_finite() for c in ("t_s", "x_m", "y_m")
    ) & pl.col("actor_id").is_not_null() & pl.col("kind").is_not_null() & pl.col("frame").is_not_null()
    kept = tracks.filter(finite)
    if kept.height < tracks.height:
        reasons.append(f"{tracks.height - kept.height} row(s) with a NULL or non-finite t_s, x_m or y_m")
    deduped = kept.unique(subset=["actor_id", "frame"], keep="first", maintain_order=True)
    if deduped.height < kept.height:
        reasons.append(f"{kept.height - deduped.height} duplicated (actor_id, frame) row(s), first kept")
    sizes = pl.DataFrame(
        {"kind": list(schema.DEFAULT_SIZE_M), "_len": [v[0] for v in schema.DEFAULT_SIZE_M.values()],
         "_wid": [v[1] for v in schema.DEFAULT_SIZE_M.values()]})
    filled = (
        deduped.join(sizes, on="kind", how="left")
        .with_columns(
            # non-finite optional values are unknown: NULL, then derived or defaulted
            *[pl.when(pl.col(c).is_finite()).then(pl.col(c)).otherwise(None).alias(c)
              for c in ("heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m")],
        )
        .with_columns(
            length_m=pl.when(pl.col("length_m") > 0).then(pl.col("length_m")).otherwise(pl.col("_len")),
            width_m=pl.when(pl.col("width_m") > 0).then(pl.col("width_m")).otherwise(pl.col("_wid")),
        )
        .select(schema.TRACKS.column_names)
        .sort("actor_id", "frame")
    )
    return filled, tracks.height - deduped.height, reasons


def write_drives(con: duckdb.DuckDBPyConnection, drives: list[DriveData]) -> list[tuple[DriveData, int]]:
    """Replace these drives (and their maps) in the file, in one transaction.

    Returns each drive with the number of track rows kept (0 when the drive was rejected).
    """
    accepted: list[tuple[DriveData, pl.DataFrame, int, str | None]] = []
    written: list[tuple[DriveData, int]] = []
    for drive in drives:
        try:
            if drive.tracks.is_empty() and drive.reject_reason:
                raise InputError(drive.reject_reason)
            tracks, dropped, reasons = clean_tracks(drive)
            if tracks.is_empty():
                raise InputError(f"{drive.source_path}: drive '{drive.drive_id}' has no usable track rows.")
        except InputError as exc:
            _reject(con, drive, str(exc))
            written.append((drive, 0))
            continue
        reason = "; ".join(([drive.reject_reason] if drive.reject_reason else []) + reasons) or None
        accepted.append((drive, tracks, dropped, reason))
        written.append((drive, tracks.height))
    if not accepted:
        return written
    ids = pl.DataFrame({"drive_id": [d.drive_id for d, *_ in accepted]})
    maps = {d.map_id: d for d, *_ in accepted if d.map_id is not None}
    con.execute("begin transaction")
    try:
        con.register("_drive_ids", ids)
        con.register("_map_ids", pl.DataFrame({"map_id": list(maps)}, schema={"map_id": pl.String}))
        for table in schema.DRIVE_TABLE_NAMES:
            con.execute(f"delete from {table} where drive_id in (select drive_id from _drive_ids)")
        # new rows for a drive: its earlier match status no longer holds, so the next match reruns it
        con.execute("delete from drive_scenarios where drive_id in (select drive_id from _drive_ids)")
        for table in schema.MAP_TABLE_NAMES:
            con.execute(f"delete from {table} where map_id in (select map_id from _map_ids)")
        for drive in maps.values():
            for table in schema.MAP_TABLE_NAMES:
                db.insert(con, table, getattr(drive, table))
        for drive, *_ in accepted:
            db.insert(con, "traffic_light_states", drive.traffic_light_states)
        with stage("kinematics"):
            con.register("tracks_raw", pl.concat([t for _, t, *_ in accepted]))
            con.execute("create or replace temp table _staged as " + query_text("staging/tracks.sql"))
            con.unregister("tracks_raw")
            con.execute("insert into tracks select * from _staged")
        for map_id, drive in maps.items():
            on_map = [d.drive_id for d, *_ in accepted if d.map_id == map_id]
            con.register("_on_map", pl.DataFrame({"drive_id": on_map}))
            staged = con.sql("select drive_id, actor_id, kind, frame, x_m, y_m, heading_rad from _staged "
                             "where drive_id in (select drive_id from _on_map)").pl()
            with stage("localisation"):
                located = locate(staged, drive.lanes)
            db.insert(con, "track_lanes", located)
        db.insert(con, "drive_inputs", pl.DataFrame([{
            "drive_id": d.drive_id, "source_format": d.source_format, "source_path": d.source_path,
            "map_id": d.map_id, "dt_s": d.dt_s, "ego_actor_id": d.ego_actor_id,
            "rows_read": d.rows_read or d.tracks.height, "rows_rejected": d.rows_rejected + dropped,
            "status": "ingested", "reject_reason": reason, "attribution": d.attribution,
        } for d, _, dropped, reason in accepted], schema=schema.DRIVE_INPUTS.polars_schema))
        con.execute("drop table _staged")
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise
    return written


def _reject(con: duckdb.DuckDBPyConnection, drive: DriveData, reason: str) -> None:
    """Record a drive as rejected; rows an earlier ingest left for the same drive_id go, so nothing stale stays."""
    for table in (*schema.DRIVE_TABLE_NAMES, "drive_scenarios"):
        con.execute(f"delete from {table} where drive_id = $d", {"d": drive.drive_id})
    rows = drive.rows_read or drive.tracks.height
    db.insert(con, "drive_inputs", pl.DataFrame([{
        "drive_id": drive.drive_id, "source_format": drive.source_format, "source_path": drive.source_path,
        "map_id": drive.map_id, "dt_s": drive.dt_s if drive.dt_s and math.isfinite(drive.dt_s) else None,
        "ego_actor_id": drive.ego_actor_id, "rows_read": rows, "rows_rejected": rows, "status": "rejected",
        "reject_reason": reason, "attribution": drive.attribution,
    }], schema=schema.DRIVE_INPUTS.polars_schema))
