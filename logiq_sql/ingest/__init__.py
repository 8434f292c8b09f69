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
from logiq_sql.ingest.base import DriveData
from logiq_sql.localise import locate
from logiq_sql.paths import query_path


FORMATS = ("commonroad", "scenarionet", "parquet")


def _reader(fmt: str) -> Callable[[Path], list[DriveData]]:
    module = importlib.import_module(f"logiq_sql.ingest.{fmt}")
    return getattr(module, f"read_{fmt}")
_SUFFIXES = {"commonroad": (".xml", ".xml.gz"), "scenarionet": (".pkl",), "parquet": (".parquet",)}


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
    """Files to read: each path as given, or the matching files inside a folder (sorted)."""
    out: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise InputError(f"{p}: no such file or folder.")
        if p.is_dir() and not (fmt == "parquet" and (p / "tracks.parquet").exists()):
            out += sorted(f for f in p.rglob("*") if f.is_file() and f.name.endswith(_SUFFIXES[fmt]))
        else:
            out.append(p)
    return out


def ingest(fmt: str, paths: Iterable[str | Path], db_path: str | Path,
           progress: Callable[[str], None] | None = None) -> IngestSummary:
    """Read every file of ``paths`` with the ``fmt`` reader into the DuckDB file ``db_path``."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format '{fmt}'.{did_you_mean(fmt, FORMATS)} Formats: {', '.join(FORMATS)}.")
    reader = _reader(fmt)
    files = expand(fmt, paths)
    con = db.connect(db_path)
    summary = IngestSummary()
    try:
        for i, path in enumerate(files, 1):
            try:
                drives = reader(path)
            except LogiqError as exc:
                _record_rejected(con, fmt, path, str(exc))
                summary.rejected += 1
                if progress:
                    progress(f"[{i}/{len(files)}] {path.name}: rejected: {exc}")
                continue
            for drive in drives:
                write_drive(con, drive)
                summary.drives += 1
                summary.rows += drive.rows_read - drive.rows_rejected
                summary.rows_rejected += drive.rows_rejected
            if progress:
                progress(f"[{i}/{len(files)}] {path.name}: {len(drives)} drive(s)")
    finally:
        con.close()
    return summary


def _record_rejected(con: duckdb.DuckDBPyConnection, fmt: str, path: Path, reason: str) -> None:
    drive_id = path.name.split(".")[0]
    con.execute("delete from drive_inputs where drive_id = $drive_id", {"drive_id": drive_id})
    db.insert(con, "drive_inputs", pl.DataFrame([{
        "drive_id": drive_id, "source_format": fmt, "source_path": str(path), "map_id": None, "dt_s": None,
        "ego_actor_id": None, "rows_read": 0, "rows_rejected": 0, "status": "rejected",
        "reject_reason": reason, "attribution": None,
    }], schema=schema.DRIVE_INPUTS.polars_schema))


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


def write_drive(con: duckdb.DuckDBPyConnection, drive: DriveData) -> None:
    """Replace one drive (and its map) in the file, in one transaction."""
    try:
        tracks, dropped, reasons = clean_tracks(drive)
        if tracks.is_empty():
            raise InputError(f"{drive.source_path}: drive '{drive.drive_id}' has no usable track rows.")
    except InputError as exc:
        _record_rejected_drive(con, drive, str(exc))
        return
    reason = "; ".join(r for r in ([drive.reject_reason] if drive.reject_reason else []) + reasons) or None
    con.execute("begin transaction")
    try:
        for table in ("tracks", "track_lanes", "traffic_light_states", "drive_inputs"):
            con.execute(f"delete from {table} where drive_id = $d", {"d": drive.drive_id})
        if drive.map_id is not None:
            for table in ("lanes", "lane_successors", "junctions", "traffic_lights"):
                con.execute(f"delete from {table} where map_id = $m", {"m": drive.map_id})
            db.insert(con, "lanes", drive.lanes)
            db.insert(con, "lane_successors", drive.lane_successors)
            db.insert(con, "junctions", drive.junctions)
            db.insert(con, "traffic_lights", drive.traffic_lights)
        db.insert(con, "traffic_light_states", drive.traffic_light_states)
        con.register("tracks_raw", tracks)
        staged = con.sql(query_path("staging/tracks.sql").read_text()).pl()
        con.unregister("tracks_raw")
        db.insert(con, "tracks", staged)
        db.insert(con, "track_lanes", locate(staged, drive.lanes))
        db.insert(con, "drive_inputs", pl.DataFrame([{
            "drive_id": drive.drive_id, "source_format": drive.source_format, "source_path": drive.source_path,
            "map_id": drive.map_id, "dt_s": drive.dt_s, "ego_actor_id": drive.ego_actor_id,
            "rows_read": drive.rows_read or drive.tracks.height,
            "rows_rejected": drive.rows_rejected + dropped, "status": "ingested",
            "reject_reason": reason, "attribution": drive.attribution,
        }], schema=schema.DRIVE_INPUTS.polars_schema))
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise


def _record_rejected_drive(con: duckdb.DuckDBPyConnection, drive: DriveData, reason: str) -> None:
    con.execute("delete from drive_inputs where drive_id = $d", {"d": drive.drive_id})
    db.insert(con, "drive_inputs", pl.DataFrame([{
        "drive_id": drive.drive_id, "source_format": drive.source_format, "source_path": drive.source_path,
        "map_id": drive.map_id, "dt_s": drive.dt_s if drive.dt_s and math.isfinite(drive.dt_s) else None,
        "ego_actor_id": drive.ego_actor_id, "rows_read": drive.rows_read or drive.tracks.height,
        "rows_rejected": drive.rows_read or drive.tracks.height, "status": "rejected",
        "reject_reason": reason, "attribution": drive.attribution,
    }], schema=schema.DRIVE_INPUTS.polars_schema))
