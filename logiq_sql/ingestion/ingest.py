"""Ingest: read drives from a source format into the canonical tables of a DuckDB file.

Every file that goes in is accounted for in ``drive_inputs``: ingested (possibly with some rows rejected) or
rejected with the reason. Re-ingesting a drive replaces it (same drive_id), so ingest is idempotent.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import duckdb
import numpy as np
import polars as pl
import pyarrow as pa

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError, LogiqError, did_you_mean
from logiq_sql.core.formats import FORMATS
from logiq_sql.core.sql import query_text, recount_coverage, registered
from logiq_sql.core.timing import stage
from logiq_sql.ingestion.localise import WORKERS, build_indexes, track_lanes_of
from logiq_sql.ingestion.readers.base import DriveData
from logiq_sql.storage import db, step_cache, tables
from logiq_sql.storage.store import PERSISTED


def reader_function(fmt: str, name: str | None = None) -> Callable:
    """The function ``name`` (default ``read_<fmt>``) of the format's reader, logiq_sql/ingestion/readers/<fmt>.py
    (core/formats.py): imported when first used, so a run loads only the reader it needs."""
    module = importlib.import_module(f"logiq_sql.ingestion.readers.{fmt}")
    return getattr(module, name or f"read_{fmt}")


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
    source = FORMATS[fmt]
    out: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise InputError(f"{p}: no such file or folder.")
        if source.folders:
            out += reader_function(fmt, source.folders)(p)
        elif p.is_dir() and not (source.drive_folder_marker and (p / source.drive_folder_marker).exists()):
            out += sorted(f for f in p.rglob("*") if f.is_file() and f.name.endswith(source.suffixes))
        else:
            out.append(p)
    return list(dict.fromkeys(out))  # a file named twice (itself and through its folder) is read once


BATCH_ROWS = 1_000_000  # drives are written in batches of about this many track rows (bounded memory)
INGEST_DUCKDB_SHARE = 0.5  # of LOGIQ_SQL_MEMORY_LIMIT, for DuckDB while ingesting (db.share_memory)


def ingest(fmt: str, paths: Iterable[str | Path], db_path: str | Path, *,
           progress: Callable[[str], None] | None = None, wait_s: float = 0.0) -> IngestSummary:
    """Read every file of ``paths`` with the ``fmt`` reader into the DuckDB file ``db_path``, published to its
    readers when every file is read (``db.open_for_write``; ``wait_s``: how long to wait for another writer)."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format '{fmt}'.{did_you_mean(fmt, FORMATS)} Formats: {', '.join(FORMATS)}.")
    reader = reader_function(fmt)
    files = expand(fmt, paths)
    summary = IngestSummary()
    batch: list[DriveData] = []
    batch_rows = 0
    seen: dict[str, str] = {}  # drive_id -> the file it came from in this run
    held: dict[str, tuple] = {}  # map_id -> (its lanes, their LaneIndex), for the run's later batches
    with db.open_for_write(db_path, wait_s, progress) as con:
        # the reader holds up to CHUNK_ROWS rows in Polars and the batch is localised in Python beside DuckDB:
        # DuckDB gets half the limit (its cache of a large file would fill all of it, and the rest needs room;
        # README "Memory")
        db.share_memory(con, INGEST_DUCKDB_SHARE)
        for i, path in enumerate(files, 1):
            count = 0
            try:
                for drive in reader(path):  # readers may stream: drives are written as batches fill up
                    batch.append(_unique(drive, seen))
                    batch_rows += drive.tracks.height
                    count += 1
                    if batch_rows >= BATCH_ROWS:
                        _count(summary, write_drives(con, batch, held))
                        batch, batch_rows = [], 0
            except LogiqError as exc:
                # the file could not be read: one rejected drive named after it
                _reject(con, _unique(DriveData(path.name.split(".")[0], fmt, str(path), math.nan, pl.DataFrame()),
                                     seen), str(exc))
                summary.rejected += 1
                if progress:
                    progress(f"[{i}/{len(files)}] {path.name}: rejected: {exc}")
                continue
            if progress:
                progress(f"[{i}/{len(files)}] {path.name}: {count} drive(s)")
        _count(summary, write_drives(con, batch, held))
    return summary


def _unique(drive: DriveData, seen: dict[str, str]) -> DriveData:
    """The drive, or, when another file of this run already gave its drive_id, a rejected drive under an id that
    names its file: the first is kept, the second is accounted for, neither replaces the other silently.
    (Ingesting the same file again, in this run or a later one, replaces the drive: ingest is idempotent.)"""
    first = seen.setdefault(drive.drive_id, drive.source_path)
    if first == drive.source_path:
        return drive
    clash = DriveData(f"{drive.drive_id} ({drive.source_path})", drive.source_format, drive.source_path,
                      drive.dt_s, pl.DataFrame(), rows_read=drive.rows_read or drive.tracks.height,
                      reject_reason=f"{drive.source_path}: drive_id '{drive.drive_id}' was already read from {first} "
                                    "in this run. Fix: give every drive its own drive_id.")
    seen[clash.drive_id] = drive.source_path
    return clash


def _count(summary: IngestSummary, written: list[tuple[DriveData, int]]) -> None:
    for drive, kept in written:
        if kept:
            summary.drives += 1
            summary.rows += kept
            summary.rows_rejected += (drive.rows_read or kept) - kept
        else:
            summary.rejected += 1


# Plausibility limits for values that reached ingest in the wrong unit or from a broken writer (docs/semantics.md,
# "Bad input"). Far beyond any real drive, so real data never trips them.
MAX_ABS_POSITION_M = 1e8  # 100,000 km: beyond any projected map frame (UTM northings reach 1e7 m)
MAX_ABS_TIME_S = 1e10  # Unix time in seconds reaches 1e10 in 2286
MAX_ABS_HEADING_RAD = 2 * math.pi + 1e-6  # beyond one turn: degrees, not radians
MAX_DT_S = 10.0  # a sample period longer than this is a time unit mistake (milliseconds as seconds)
MAX_ABS_SPEED_MPS = 1000.0  # a given speed or acceleration beyond this is a broken value: NULL, then derived
MAX_ABS_ACCEL_MPS2 = 1000.0
MAX_MEDIAN_SPEED_MPS = 100.0  # 360 km/h as the median speed of a drive's moving samples: positions not in metres


def clean_tracks(drive: DriveData) -> tuple[pl.DataFrame, int, list[str]]:
    """``clean_batch`` of one drive: its kept rows, how many were dropped and the reasons; raises its InputError."""
    (result,) = clean_batch([drive])
    if isinstance(result, InputError):
        raise result
    return result


_BROKEN_LIMITS = (("speed_mps", MAX_ABS_SPEED_MPS), ("accel_mps2", MAX_ABS_ACCEL_MPS2))


def _dropped_reasons(finite: int, range_: int, keys: int) -> list[str]:
    """The reasons for rows dropped as unusable, each row counted under its first failing check."""
    reasons = []
    if finite:
        reasons.append(f"{finite} row(s) with a NULL, NaN or infinite t_s, x_m or y_m dropped")
    if range_:
        reasons.append(f"{range_} row(s) with |x_m| or |y_m| above {MAX_ABS_POSITION_M:.0e} m or |t_s| "
                       f"above {MAX_ABS_TIME_S:.0e} s dropped")
    if keys:
        reasons.append(f"{keys} row(s) with a NULL actor_id, kind or frame dropped")
    return reasons


def _broken_reason(count: int, col: str, limit: float) -> str:
    return f"{count} {col} value(s) beyond +-{limit:g} set to NULL and derived from positions"


def _filled(rows: pl.DataFrame) -> pl.DataFrame:
    """Non-finite optional values as NULL (then derived or defaulted), sizes not above 0 as the kind's default."""
    kinds = list(schema.DEFAULT_SIZE_M)
    default = {name: pl.col("kind").replace_strict(kinds, [v[i] for v in schema.DEFAULT_SIZE_M.values()],
                                                   default=None, return_dtype=pl.Float64)
               for i, name in enumerate(("length_m", "width_m"))}
    return (
        rows.with_columns(
            # non-finite optional values are unknown: NULL, then derived or defaulted
            *[pl.when(pl.col(c).is_finite()).then(pl.col(c)).otherwise(None).alias(c)
              for c in ("heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m")],
        )
        .with_columns(pl.when(pl.col(c) > 0).then(pl.col(c)).otherwise(default[c]).alias(c) for c in default)
    )


def _one_row_per_frame(rows: pl.DataFrame, dt_s: float) -> tuple[pl.DataFrame, list[str]]:
    """One row per (actor_id, frame). Exact copies of a row are one row. Several samples rounding to one frame
    (jitter, a stray extra sample): the one nearest to frame * dt_s is kept. Rows with the same actor and t_s but
    different values contradict each other: all of them are dropped, so that frame is missing for the actor."""
    reasons = []
    # the usual case, checked at once: no two rows share an (actor, frame) or an (actor, t_s), so there are no
    # exact copies, no contradictions and no second sample in a frame (the steps below would drop nothing)
    clash = rows.select(pl.struct("actor_id", "frame").is_duplicated().any().alias("frame"),
                        pl.struct("actor_id", "t_s").is_duplicated().any().alias("t")).row(0)
    if not any(clash):
        return rows, reasons
    unique = rows.unique(maintain_order=True)
    if unique.height < rows.height:
        reasons.append(f"{rows.height - unique.height} exact duplicate row(s) dropped")
    conflict = pl.len().over("actor_id", "t_s") > 1
    consistent = unique.filter(~conflict)
    if consistent.height < unique.height:
        example = unique.filter(conflict).sort("actor_id", "t_s").row(0, named=True)
        reasons.append(f"{unique.height - consistent.height} row(s) giving one actor different values at the same "
                       f"t_s dropped (e.g. actor_id '{example['actor_id']}' at t_s = {example['t_s']:g})")
    if dt_s and math.isfinite(dt_s) and dt_s > 0:
        off_grid = (pl.col("t_s") - pl.col("frame") * dt_s).abs()
        nearest = consistent.sort(off_grid, "t_s").unique(subset=["actor_id", "frame"], keep="first")
    else:
        nearest = consistent.unique(subset=["actor_id", "frame"], keep="first")
    if nearest.height < consistent.height:
        reasons.append(f"{consistent.height - nearest.height} row(s) falling in a frame their actor already has "
                       f"dropped (the row nearest to frame * dt_s kept)")
    return nearest, reasons


def clean_batch(drives: list[DriveData]) -> list[tuple[pl.DataFrame, int, list[str]] | InputError]:
    """Check the rows of many drives with one set of rules, each rule evaluated over all their rows at once (a
    drive's rows stay apart by its position in ``drives``); a batch of one drive is checked by the same code.

    For each drive, in order: the InputError that rejects it (a column missing; an unknown kind; the whole drive
    evidently in another unit: sample period, headings, frame steps or speeds, docs/semantics.md "Bad input"), or
    its kept rows (sorted by actor_id, frame), how many rows were dropped and the reasons. Rows that cannot be
    placed, or whose time or position is not a usable number, are dropped (each counted under its first failing
    check); broken speeds and accelerations become NULL; one row per (actor, frame) (``_one_row_per_frame``);
    optional values filled (``_filled``).
    """
    results: list = [None] * len(drives)
    pick = []
    for i, drive in enumerate(drives):
        missing = [c for c in ("drive_id", "actor_id", "kind", "frame", "t_s", "x_m", "y_m")
                   if c not in drive.tracks.columns]
        if missing:
            results[i] = InputError(f"{drive.source_path}: tracks lack column(s) {', '.join(missing)}.")
        elif drive.tracks.is_empty():
            results[i] = _rejection(drive, {"bad_kinds": [], "heading": None, "frame_step": None, "moving": None}
                                    ) or (schema.empty(schema.TRACKS), 0, [])
        else:
            pick.append(i)
    if not pick:
        return results
    keys_ok, finite, in_range = _row_checks()
    frames = [drives[i].tracks if drives[i].tracks.schema == schema.TRACKS.polars_schema
              else drives[i].tracks.select(pl.col(c).cast(t) for c, t in schema.TRACKS.polars_schema.items())
              for i in pick]
    position = pl.Series("_d", np.repeat(np.arange(len(pick), dtype=np.uint32), [f.height for f in frames])
                         ).set_sorted()
    rows = pl.concat(frames).with_columns(position)
    # one order for the rules and the output, (drive, actor_id, frame), ties in the order given. Readers mostly
    # give it already: only the drives out of it are sorted
    after = ~pl.col("_d").eq(pl.col("_d").shift()).fill_null(False) | pl.col("actor_id").gt(
        pl.col("actor_id").shift()) | (pl.col("actor_id").eq(pl.col("actor_id").shift())
                                       & pl.col("frame").ge(pl.col("frame").shift()))
    unsorted = rows.filter(~after.fill_null(False))["_d"].unique().to_list()
    if unsorted:
        for d in unsorted:
            frames[d] = frames[d].sort("actor_id", "frame", maintain_order=True)
        rows = pl.concat(frames).with_columns(position)
    del frames
    # after the previous row of the same actor of the same drive (False on a drive's or an actor's first row)
    same_track = (pl.col("_d").eq(pl.col("_d").shift()) & pl.col("actor_id").eq(pl.col("actor_id").shift())
                  ).fill_null(False)
    placed = pl.col("actor_id").is_not_null() & pl.col("frame").is_not_null()
    unknown = pl.col("kind").is_not_null() & ~pl.col("kind").is_in(schema.OBJECT_KINDS)
    facts = rows.group_by("_d").agg(
        bad_kinds=pl.col("kind").filter(unknown).unique(),
        heading=pl.col("heading_rad").filter(pl.col("heading_rad").is_finite()).abs().max(),
        finite=(~finite).sum(), range=(finite & ~in_range).sum(), keys=(finite & in_range & ~keys_ok).sum(),
        rows=pl.len(),
    )
    # consecutive samples of an actor (rows that can be placed, with finite time and position): their frame
    # step and speed; the medians over steps that advance the frame (the speed only where above 0.5 m/s)
    ok = pl.all_horizontal(pl.col(c).is_finite() for c in ("t_s", "x_m", "y_m"))
    steps = (
        rows.filter(ok & placed)
        .select(
            "_d",
            frames=pl.when(same_track).then(pl.col("frame").diff()),
            speed=pl.when(same_track).then((pl.col("x_m").diff() ** 2 + pl.col("y_m").diff() ** 2).sqrt()
                                           / pl.col("t_s").diff()),
        )
        .group_by("_d")
        .agg(frame_step=pl.col("frames").filter(pl.col("frames") > 0).median(),
             moving=pl.col("speed").filter((pl.col("frames") > 0) & pl.col("speed").is_finite()
                                           & (pl.col("speed") > 0.5)).median())
    )
    # (the usual case: every row kept, and no copy of them made)
    kept = rows if not facts.select(pl.sum_horizontal("finite", "range", "keys").sum()).item() else rows.filter(
        keys_ok & finite & in_range)
    del rows
    broken = {col: pl.col(col).is_finite() & (pl.col(col).abs() > limit) for col, limit in _BROKEN_LIMITS}
    # a drive where an actor may have two rows in one frame or at one t_s (the frame or t_s not rising from one
    # of its rows to the next) goes through _one_row_per_frame
    kept_facts = kept.with_columns(repeats=same_track & ~((pl.col("frame") > pl.col("frame").shift())
                                                          & (pl.col("t_s") > pl.col("t_s").shift()))
                                   ).group_by("_d").agg(repeats=pl.col("repeats").any(), kept=pl.len(),
                                                        **{col: b.sum() for col, b in broken.items()})
    facts = (facts.join(steps, on="_d", how="left").join(kept_facts, on="_d", how="left")
             .with_columns(pl.col("kept").fill_null(0), pl.col("repeats").fill_null(False)).sort("_d"))
    kept = kept.with_columns(pl.when(b).then(None).otherwise(pl.col(col)).alias(col) for col, b in broken.items())
    # the drives with repeats as they are before filling (NaN and NULL differ when telling copies apart)
    repeating = facts.filter(pl.col("repeats"))["_d"]
    unfilled = kept.filter(pl.col("_d").is_in(repeating.implode())).partition_by(
        "_d", as_dict=True, include_key=False) if repeating.len() else {}
    out = kept.pipe(_filled).select(*schema.TRACKS.column_names, "_d")
    del kept
    offset = 0
    for fact in facts.iter_rows(named=True):  # per drive: the decision and its message, the drive's slice
        drive = drives[pick[fact["_d"]]]
        mine = out.slice(offset, fact["kept"])
        offset += fact["kept"]
        rejection = _rejection(drive, fact)
        if rejection is not None:
            results[pick[fact["_d"]]] = rejection
            continue
        reasons = _dropped_reasons(fact["finite"], fact["range"], fact["keys"])
        reasons += [_broken_reason(fact[col], col, limit) for col, limit in _BROKEN_LIMITS if fact[col]]
        mine = mine.drop("_d")
        if fact["repeats"]:
            mine, dup_reasons = _one_row_per_frame(unfilled[(fact["_d"],)], drive.dt_s)
            mine = _filled(mine).select(schema.TRACKS.column_names).sort("actor_id", "frame")
            reasons += dup_reasons
        results[pick[fact["_d"]]] = (mine, fact["rows"] - mine.height, reasons)
    return results


def _rejection(drive: DriveData, fact: dict) -> InputError | None:
    """Why the whole drive is refused (its rows in another unit, an unknown kind), from its facts, or None."""
    where = f"{drive.source_path}: drive '{drive.drive_id}'"
    dt_s = drive.dt_s
    if fact["bad_kinds"]:
        bad_kinds = sorted(fact["bad_kinds"])
        return InputError(
            f"{drive.source_path}: column 'kind' has unknown value(s) {', '.join(map(repr, bad_kinds))}."
            f"{did_you_mean(str(bad_kinds[0]), schema.OBJECT_KINDS)}\n\n"
            f"Hint: kinds are the spec's evaluation_object_kind values: {', '.join(schema.OBJECT_KINDS)}."
        )
    if dt_s and math.isfinite(dt_s) and dt_s > MAX_DT_S:
        return InputError(f"{where}: the sample period dt_s is {dt_s:g} s. Fix: write t_s in seconds (milliseconds "
                          "divided by 1000) and dt_s in seconds.")
    worst = fact["heading"]
    if worst is not None and worst > MAX_ABS_HEADING_RAD:
        return InputError(f"{where}: column 'heading_rad' reaches {worst:g}, more than one turn (2 pi). Fix: "
                          "write headings in radians (degrees * pi / 180).")
    frame_step = fact["frame_step"]
    if frame_step is not None and frame_step >= 2:
        return InputError(f"{where}: consecutive samples of an actor are a median {frame_step:g} frames apart, so "
                          f"the timestamps do not step by dt_s = {dt_s:g} s. Fix: write t_s in seconds and give the "
                          "drive's true sample period as dt_s (drives.parquet), or leave dt_s out to derive it.")
    moving = fact["moving"]
    if moving is not None and moving > MAX_MEDIAN_SPEED_MPS:
        return InputError(f"{where}: actors move at a median {moving:,.0f} m/s between samples. Fix: write "
                          "x_m and y_m in metres (millimetres divided by 1000) and t_s in seconds.")
    return None


def _row_checks() -> tuple[pl.Expr, pl.Expr, pl.Expr]:
    """Rows that can be placed (actor, kind, frame), whose time and position are finite, and within range."""
    keys_ok = pl.all_horizontal(pl.col(c).is_not_null() for c in ("actor_id", "kind", "frame"))
    finite = pl.all_horizontal(pl.col(c).is_not_null() & pl.col(c).is_finite() for c in ("t_s", "x_m", "y_m"))
    in_range = ((pl.col("x_m").abs() <= MAX_ABS_POSITION_M) & (pl.col("y_m").abs() <= MAX_ABS_POSITION_M)
                & (pl.col("t_s").abs() <= MAX_ABS_TIME_S))
    return keys_ok, finite, in_range


def write_drives(con: duckdb.DuckDBPyConnection, drives: list[DriveData],
                 held: dict[str, tuple] | None = None) -> list[tuple[DriveData, int]]:
    """Replace these drives (and their maps) in the file, in one transaction. ``held``: the lane indexes of the
    maps of earlier batches of the run (``_map_rows``), kept for the next.

    Returns each drive with the number of track rows kept (0 when the drive was rejected).
    """
    accepted: list[tuple[DriveData, pl.DataFrame, int, str | None]] = []
    written: list[tuple[DriveData, int]] = []
    held = {} if held is None else held
    # a drive read twice into one batch (a file named twice) is written once, as a later ingest would replace it
    unique = list({d.drive_id: d for d in drives}.values())
    cleaned = clean_batch(unique)  # the checks of the whole batch at once
    for drive, result in zip(unique, cleaned, strict=True):
        try:
            if drive.tracks.is_empty() and drive.reject_reason:
                raise InputError(drive.reject_reason)
            if isinstance(result, InputError):
                raise result
            tracks, dropped, reasons = result
            if tracks.is_empty():
                raise InputError(f"{drive.source_path}: drive '{drive.drive_id}' has no usable track rows"
                                 + (f" ({'; '.join(reasons)})." if reasons else "."))
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
    keys = drive_keys(con, ids["drive_id"].to_list())
    maps = {d.map_id: d for d, *_ in accepted if d.map_id is not None}
    # a map an earlier batch of this run wrote from the same lanes frame (the Parquet reader gives every drive of a
    # map the same one: ``held``) is in the file as it is: not deleted and written again for every batch
    rewritten = {m: d for m, d in maps.items() if not _held(held, m, d.lanes)}
    map_ids = pl.DataFrame({"map_id": list(rewritten)}, schema={"map_id": pl.String})
    # new rows for these drives, or for the maps other drives read: their cached steps no longer hold
    stale = ("select drive_id from _drive_ids union all select drive_id from drive_inputs "
             "where map_id in (select map_id from _map_ids)")
    with registered(con, "_drive_ids", ids), registered(con, "_map_ids", map_ids):
        step_cache.drop_drives(con, stale)  # the cache's own file: before the transaction, which writes this one
    con.execute("begin transaction")
    try:
        with registered(con, "_drive_ids", ids), registered(con, "_map_ids", map_ids):
            # a drive has rows in the file only with its drive_inputs row (written in one transaction, or
            # rejected by _reject, which writes one): drives new to the file have nothing to delete, and the deletes
            # would scan the drive_id of every stored row once per batch
            if con.execute("select count(*) from drive_inputs where drive_id in (select drive_id from _drive_ids)"
                           ).fetchall()[0][0]:
                for table in schema.DRIVE_TABLE_NAMES:
                    con.execute(f"delete from {table} where drive_id in (select drive_id from _drive_ids)")
                # new rows for a drive: its earlier matches and match status no longer hold; the next match reruns it
                con.execute("delete from drive_scenarios where drive_id in (select drive_id from _drive_ids)")
                _drop_outputs(con, ids["drive_id"].to_list())
            step_cache.set_versions(con, stale)
            for table in schema.MAP_TABLE_NAMES:
                con.execute(f"delete from {table} where map_id in (select map_id from _map_ids)")
        # one insert per table for the whole batch (one per map or drive paid DuckDB's per-statement cost each time)
        for table in schema.MAP_TABLE_NAMES:
            _insert_all(con, table, [getattr(drive, table) for drive in rewritten.values()])
        _insert_all(con, "traffic_light_states", [drive.traffic_light_states for drive, *_ in accepted])
        # one ordered pass over the batch: its rows (each drive's sorted by actor_id, frame: clean_batch) with their
        # keys, the kinematics of staging/tracks.sql evaluated once over that order, the result stored as tracks and
        # localised as it is (no read back from the file)
        with stage("kinematics"):
            staged = _staged(con, with_keys([t for _, t, *_ in accepted], [keys[d.drive_id] for d, *_ in accepted]
                                             ).to_arrow())
            with registered(con, "_staged", staged):  # Arrow: read by DuckDB as it is
                con.execute(f"insert into tracks ({', '.join(staged.column_names)}) "
                            f"select {', '.join(staged.column_names)} from _staged")
        with stage("localisation"):
            located = track_lanes_of(staged, _map_rows(accepted, maps, held))
        del staged
        with registered(con, "_located", located):
            con.execute(f"insert into track_lanes ({', '.join(located.column_names)}) "
                        f"select {', '.join(located.column_names)} from _located")
        del located
        tables.insert(con, "drive_inputs", pl.DataFrame([{
            "drive_id": d.drive_id, "source_format": d.source_format, "source_path": d.source_path,
            "map_id": d.map_id, "dt_s": d.dt_s, "ego_actor_id": d.ego_actor_id,
            "rows_read": d.rows_read or d.tracks.height, "rows_rejected": d.rows_rejected + dropped,
            "status": "ingested", "reject_reason": reason, "attribution": d.attribution,
            "drive_key": keys[d.drive_id],
        } for d, _, dropped, reason in accepted], schema=schema.STORED_DRIVE_INPUTS.polars_schema))
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise
    return written


KINEMATICS = ("heading_rad", "speed_mps", "accel_mps2")  # what staging/tracks.sql completes


def _staged(con: duckdb.DuckDBPyConnection, raw: pa.Table) -> pa.Table:
    """The stored tracks of a batch's rows with their keys (``with_keys``): their own columns, with the kinematics
    staging/tracks.sql completes over their order. The query returns a row for each row of ``raw`` in its order
    (its windows run over that order); its row_key column checks that.

    DuckDB runs windows over an empty ``OVER ()`` on one thread, so the batch is cut at track boundaries into a
    part per core (``kinematics_parts``), each run on a cursor of its own at the same time: the query looks at no
    row of another track, so the parts give the rows the whole batch gives."""
    parts = kinematics_parts(raw["track_no"].to_numpy(), WORKERS)

    def run(part: pa.Table) -> pa.Table:
        with con.cursor() as cur, registered(cur, "tracks_raw", part):
            return cur.sql(query_text("staging/tracks.sql")).to_arrow_table()
    with ThreadPoolExecutor(len(parts)) as pool:
        done = pa.concat_tables(pool.map(run, [raw.slice(a, b - a) for a, b in parts])).combine_chunks()
    if not done["row_key"].equals(raw["row_key"]):
        raise RuntimeError("staging/tracks.sql returned the rows out of their order: not stored.")
    return pa.table([done[c] if c in KINEMATICS else raw[c] for c in schema.STORED_TRACKS.column_names],
                    names=list(schema.STORED_TRACKS.column_names))


def kinematics_parts(track_no: np.ndarray, parts: int) -> list[tuple[int, int]]:
    """``(start, end)`` of up to ``parts`` runs of rows of about equal length that cover ``track_no`` in order,
    each cut where the track changes (a track is never split)."""
    n = len(track_no)
    starts = np.flatnonzero(np.diff(track_no)) + 1  # the rows where a new track begins
    cuts = np.unique(starts[np.searchsorted(starts, [n * k // parts for k in range(1, parts)])
                            .clip(max=len(starts) - 1)]) if len(starts) else np.array([], dtype=np.int64)
    bounds = [0, *cuts.tolist(), n]
    return [(a, b) for a, b in zip(bounds, bounds[1:]) if b > a] or [(0, n)]


def _map_rows(accepted: list, maps: dict[str, DriveData], held: dict[str, tuple]) -> list:
    """For each map, the indices of the batch's rows on it (each accepted drive's rows follow the previous
    drive's), its lanes and their index: built once per run for a lanes frame a reader gives again (the Parquet
    reader gives every drive of a map the same frame), kept in ``held`` (map_id -> (lanes, index))."""
    on_map: dict[str, list[np.ndarray]] = {m: [] for m in maps}
    offset = 0
    for drive, tracks, *_ in accepted:
        if drive.map_id is not None:
            on_map[drive.map_id].append(np.arange(offset, offset + tracks.height))
        offset += tracks.height
    new = [m for m, drive in maps.items() if not drive.lanes.is_empty() and not _held(held, m, drive.lanes)]
    for m, index in zip(new, build_indexes([maps[m].lanes for m in new]), strict=True):
        held[m] = (maps[m].lanes, index)
    return [(np.concatenate(on_map[m]), drive.lanes, held[m][1] if m in held else None)
            for m, drive in maps.items()]


def _held(held: dict[str, tuple], map_id: str, lanes: pl.DataFrame) -> bool:
    """This run has already written and indexed map ``map_id`` from this very lanes frame (``_map_rows``)."""
    return map_id in held and held[map_id][0] is lanes


def drive_keys(con: duckdb.DuckDBPyConnection, drive_ids: list[str]) -> dict[str, int]:
    """``drive_key`` of each drive; refuses a key another drive of the file already has (two digests alike,
    about one chance in 10^10 among a million drives): joining on it would mix the two drives."""
    keys = {d: schema.drive_key(d) for d in drive_ids}
    if len(set(keys.values())) < len(keys):
        raise InputError(f"two drives of this batch have the same drive_key: {sorted(keys)}. Fix: rename one.")
    with registered(con, "_new_keys", pl.DataFrame({"drive_id": list(keys), "drive_key": list(keys.values())})):
        clash = con.execute("select n.drive_id, d.drive_id from _new_keys as n inner join drive_inputs as d "
                            "on n.drive_key = d.drive_key and n.drive_id <> d.drive_id").fetchall()
    if clash:
        raise InputError(f"drive '{clash[0][0]}' has the drive_key of drive '{clash[0][1]}' already in the file. "
                         "Fix: give one of them another drive_id.")
    return keys


def with_keys(tracks: list[pl.DataFrame], keys: list[int]) -> pl.DataFrame:
    """The rows of drives (each drive's in (actor_id, frame) order, none empty), one drive after the other, with
    their integer keys (schema.TRACK_KEYS; ``keys``: each drive's drive_key) and the ``track_no``
    staging/tracks.sql's windows use (different for neighbouring tracks). Each drive's rows are a known range, so
    the keys are offsets within it (no grouping by the string ids)."""
    heights = np.array([t.height for t in tracks], dtype=np.int64)
    starts = np.cumsum(heights) - heights
    rows = pl.concat(tracks)
    new_track = (pl.col("actor_id") != pl.col("actor_id").shift()).fill_null(True)
    first = np.zeros(rows.height, dtype=bool)
    first[starts] = True  # a drive's first row starts a track, whatever its actor_id
    track_no = np.cumsum(rows.select(new_track).to_series().to_numpy() | first) - 1
    return rows.with_columns(
        track_no=pl.Series(track_no, dtype=pl.UInt32),
        drive_key=pl.Series(np.repeat(np.asarray(keys, dtype=np.int64), heights)),
        actor_key=pl.Series(track_no - np.repeat(track_no[starts], heights) + 1),
        row_key=pl.Series(np.arange(rows.height, dtype=np.int64) - np.repeat(starts, heights) + 1),
    )


def _insert_all(con: duckdb.DuckDBPyConnection, table: str, frames: list[pl.DataFrame]) -> None:
    """Append the rows of every frame to ``table`` in one insert."""
    frames = [f for f in frames if not f.is_empty()]
    if frames:
        tables.insert(con, table, pl.concat(frames, how="diagonal_relaxed"))


def _reject(con: duckdb.DuckDBPyConnection, drive: DriveData, reason: str) -> None:
    """Record a drive as rejected; rows an earlier ingest left for the same drive_id go, so nothing stale stays.
    One transaction: a run killed here leaves the drive as it was before, never without its drive_inputs row."""
    rows = drive.rows_read or drive.tracks.height
    rejected = pl.DataFrame({"drive_id": [drive.drive_id]}, schema={"drive_id": pl.String})
    with registered(con, "_rejected", rejected):
        step_cache.drop_drives(con, "select drive_id from _rejected")  # its own file: outside the transaction
    con.execute("begin transaction")
    try:
        for table in (*schema.DRIVE_TABLE_NAMES, "drive_scenarios"):
            con.execute(f"delete from {table} where drive_id = $d", {"d": drive.drive_id})
        _drop_outputs(con, [drive.drive_id])
        with registered(con, "_rejected", rejected):
            step_cache.set_versions(con, "select drive_id from _rejected")
        tables.insert(con, "drive_inputs", pl.DataFrame([{
            "drive_id": drive.drive_id, "source_format": drive.source_format, "source_path": drive.source_path,
            "map_id": drive.map_id, "dt_s": drive.dt_s if drive.dt_s and math.isfinite(drive.dt_s) else None,
            "ego_actor_id": drive.ego_actor_id, "rows_read": rows, "rows_rejected": rows, "status": "rejected",
            "reject_reason": reason, "attribution": drive.attribution, "drive_key": schema.drive_key(drive.drive_id),
        }], schema=schema.STORED_DRIVE_INPUTS.polars_schema))
        con.execute("commit")
    except BaseException:
        con.execute("rollback")
        raise


def _drop_outputs(con: duckdb.DuckDBPyConnection, drive_ids: list[str]) -> None:
    """A drive that is re-ingested or now rejected keeps no matches, and no kept relation tables, from an earlier
    run of its old data (drives, matches and relations would report them until the next match); the coverage
    histograms are recounted without its matches."""
    with registered(con, "_stale", pl.DataFrame({"drive_id": drive_ids}, schema={"drive_id": pl.String})):
        have = {r[0] for r in con.execute("select table_name from duckdb_tables() where not temporary").fetchall()}
        for table in (t for t in PERSISTED if t in have):  # kept whether or not the drive had matches
            con.execute(f"delete from {table} where drive_id in (select drive_id from _stale)")
        if not con.execute("select count(*) from matches where drive_id in (select drive_id from _stale)"
                           ).fetchall()[0][0]:
            return
        for table in ("match_phases", "kpis", "coverage_samples"):
            if table in have:
                con.execute(f"delete from {table} where match_id in (select match_id from matches "
                            "where drive_id in (select drive_id from _stale))")
        con.execute("delete from matches where drive_id in (select drive_id from _stale)")
        recount_coverage(con)
