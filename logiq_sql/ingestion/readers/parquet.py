"""Canonical Parquet: bring any other source in by writing the canonical tables as Parquet.

``PATH`` is either a ``tracks.parquet`` file or a folder holding it, optionally beside ``drives.parquet``
(drive_id, dt_s, map_id, ego_actor_id) and the map tables ``lanes.parquet``, ``lane_successors.parquet``,
``junctions.parquet``, ``traffic_lights.parquet``, ``traffic_light_states.parquet`` (columns as in
docs/tables.md).

Required track columns: drive_id, actor_id, kind, t_s, x_m, y_m. Optional: is_ego (default false), frame
(default round(t_s / dt_s)), heading_rad, speed_mps, accel_mps2 (derived when absent), length_m, width_m
(default by kind). dt_s, when no drives.parquet gives it, is the median step of t_s in the drive.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.batching import batches
from logiq_sql.core.errors import InputError, did_you_mean
from logiq_sql.ingestion.readers.base import DriveData

REQUIRED = ("drive_id", "actor_id", "kind", "t_s", "x_m", "y_m")
_NUMERIC = ("t_s", "x_m", "y_m", "heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m")


def _read(path: Path) -> pl.DataFrame:
    try:
        return pl.read_parquet(path)
    except Exception as exc:  # polars raises several types for corrupt files
        raise InputError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc}).") from None


def check_table(frame: pl.DataFrame, table: schema.Table, path: str | Path,
                required: tuple[str, ...] | None = None) -> pl.DataFrame:
    """``frame`` in the columns and types of ``table``: a missing required column (default: the table's non-NULL
    ones) or a column that does not convert is an error naming ``path``, the column and the fix."""
    if required is None:
        required = tuple(c.name for c in table.columns if not c.nullable)
    for col in required:
        if col not in frame.columns:
            raise InputError(
                f"{path}: missing column '{col}'.{did_you_mean(col, frame.columns)}\n\n"
                f"Hint: {table.name} needs {', '.join(required)}; see docs/tables.md."
            )
    out = []
    for c in table.columns:
        if c.name not in frame.columns:
            out.append(pl.lit(None, dtype=c.dtype).alias(c.name))
            continue
        try:
            out.append(frame.select(pl.col(c.name).cast(c.dtype, strict=True)).to_series())
        except pl.exceptions.PolarsError:
            raise InputError(f"{path}: column '{c.name}' is {frame.schema[c.name]}, which does not convert to "
                             f"{c.dtype}.\n\nHint: write {c.name} as {c.dtype}; see docs/tables.md.") from None
    return frame.select(out)


# drives are read from the file a few million rows at a time (a drive is never split): memory stays bounded on
# large files whatever the drives' sizes (a fixed count of drives at a time can be any number of rows); this size
# keeps the reader's peak well inside the memory bound, a smaller one costs more CPU (benchmarks/README.md)
CHUNK_ROWS = 2_000_000


def _schema(path: Path) -> dict[str, pl.DataType]:
    try:
        return dict(pl.read_parquet_schema(path))
    except Exception as exc:  # polars raises several types for corrupt files
        raise InputError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc}).") from None


def read_parquet(path: str | Path) -> Iterator[DriveData]:
    """Drives of a canonical Parquet file or folder, read a few hundred drives at a time."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    tracks_file = path / "tracks.parquet" if path.is_dir() else path
    check_track_columns(_schema(tracks_file), tracks_file)
    drives_meta: dict[str, dict] = {}
    if path.is_dir() and (folder / "drives.parquet").exists():
        drives_meta = drive_metadata(_read(folder / "drives.parquet"), folder / "drives.parquet")
    maps = {t.name: check_table(_read(folder / f"{t.name}.parquet"), t, folder / f"{t.name}.parquet")
            for t in (*schema.MAP_TABLES, schema.TRAFFIC_LIGHT_STATES)
            if path.is_dir() and (folder / f"{t.name}.parquet").exists()}
    yield from read_drives(pl.scan_parquet(tracks_file), drives_meta, maps, tracks_file, folder / "drives.parquet",
                           "parquet")


def check_track_columns(columns: dict[str, pl.DataType], where: str | Path) -> None:
    """The required track columns are there and the numeric ones are numbers (``where`` names the input)."""
    unknown = [c for c in columns if c not in schema.TRACKS.column_names]
    for col in REQUIRED:
        if col not in columns:
            raise InputError(
                f"{where}: missing column '{col}'.{did_you_mean(col, unknown, cutoff=0.5)}\n\n"
                f"Hint: tracks need {', '.join(REQUIRED)}; see docs/tables.md."
            )
    for col in _NUMERIC:
        if col in columns and not columns[col].is_numeric():
            raise InputError(
                f"{where}: column '{col}' is {columns[col]}, not a number.\n\n"
                f"Hint: write {col} as a float in the unit its name says."
            )


def drive_metadata(frame: pl.DataFrame, where: str | Path) -> dict[str, dict]:
    """drives.parquet (drive_id, dt_s, map_id, ego_actor_id, attribution) as drive_id -> row."""
    if "drive_id" not in frame.columns:
        raise InputError(f"{where}: missing column 'drive_id'.{did_you_mean('drive_id', frame.columns)}\n\n"
                         "Hint: drives need drive_id and may give dt_s, map_id, ego_actor_id; see docs/tables.md.")
    return {str(r["drive_id"]): r for r in frame.to_dicts()}


def read_drives(lazy: pl.LazyFrame, drives_meta: dict[str, dict], maps: dict[str, pl.DataFrame],
                tracks_where: str | Path, drives_where: str | Path, source_format: str) -> Iterator[DriveData]:
    """The drives of canonical track rows (a Parquet scan, or frames given to ``match_frames``), a few million
    rows at a time; every drive of ``drives_meta`` is accounted for, a drive without rows as rejected."""
    lazy = lazy.with_columns(pl.col("drive_id").cast(pl.String), pl.col("actor_id").cast(pl.String))
    # each map's rows and each drive's light states, split once: filtering the whole table per drive grew with
    # drives x rows (the states of 4,000 drives at tier L)
    parts = {name: _Parts(frame, "drive_id" if name == "traffic_light_states" else "map_id")
             for name, frame in maps.items()}
    try:
        # rows per drive in order of first row, and where each drive's last row is, without holding every row's
        # drive_id
        sizes = lazy.select("drive_id").with_row_index("_row").group_by("drive_id", maintain_order=True).agg(
            pl.len().alias("len"), pl.col("_row").min().alias("first"), pl.col("_row").max().alias("last")).collect()
    except pl.exceptions.PolarsError as exc:
        what = "Parquet file" if source_format == "parquet" else "frame"
        raise InputError(f"{tracks_where}: not a readable {what} ({type(exc).__name__}: {exc}).") from None
    if sizes.height == 0:
        raise InputError(f"{tracks_where}: no rows. Fix: write the drive's track rows, or leave the file out.")
    orphans = sizes.filter(pl.col("drive_id").is_null())["len"].sum()
    if orphans:
        # rows of no drive cannot be accounted to one: the file is refused rather than those rows lost
        raise InputError(f"{tracks_where}: {orphans} row(s) have a NULL drive_id. Fix: give every row the "
                         "drive it belongs to.")
    drive_ids = sizes["drive_id"].to_list()
    # a drive that drives.parquet lists but tracks.parquet has no row of is rejected, not forgotten
    for drive_id in sorted(set(drives_meta) - set(drive_ids)):
        meta = drives_meta[drive_id]
        yield DriveData(drive_id=drive_id, source_format=source_format, source_path=str(tracks_where),
                        dt_s=meta.get("dt_s") or math.nan, tracks=pl.DataFrame(), map_id=meta.get("map_id"),
                        reject_reason=f"{tracks_where}: drive '{drive_id}' is listed in {Path(drives_where).name} but "
                                      f"has no track rows. Fix: add its rows to {Path(tracks_where).name} or remove "
                                      f"it from {Path(drives_where).name}.")
    for chunk in _chunks(lazy, sizes):
        in_chunk = chunk.group_by("drive_id", maintain_order=True).len()
        # the drives of a chunk are checked and cast a million rows at a time (memory stays that of a chunk)
        split = batches(in_chunk.iter_rows(), SPLIT_ROWS)
        runs = by_drive(chunk, in_chunk) if len(split) > 1 else None  # a chunk of one part is not cut
        for part_ids in split:
            part = (chunk if len(split) == 1
                    else pl.concat([runs[d] for d in part_ids]) if runs is not None
                    else chunk.filter(pl.col("drive_id").is_in(part_ids)))
            drives = _drives_at_once(part, drives_meta, parts, tracks_where, drives_where, source_format)
            if drives is None:  # a column does not convert: drive by drive, which says where (and yields before)
                for (drive_id,), rows in part.group_by("drive_id", maintain_order=True):
                    yield _drive(str(drive_id), rows, drives_meta.get(str(drive_id), {}), parts, tracks_where,
                                 drives_where, source_format)
                continue
            del part
            drives.reverse()
            while drives:  # each drive's rows go once the caller is done with them
                yield drives.pop()
        del chunk


def _chunks(lazy: pl.LazyFrame, sizes: pl.DataFrame) -> Iterator[pl.DataFrame]:
    """The rows of whole drives, a few million at a time, reading the file once in its order: ``CHUNK_ROWS`` rows
    are read at a time, and the drives whose last row (``sizes``: drive_id, len, first, last) has been read go out,
    the rest wait for their remaining rows. When the drives are so interleaved that the waiting rows outgrow the
    bound, the drives not yet given are read a few million rows at a time, each chunk one filtered scan of the part
    of the file between its drives' first and last rows."""
    total = int(sizes["len"].sum())
    by_last = sizes.sort("last")
    # the rows that may wait besides the chunk read: a chunk's worth, or more for a drive larger than a chunk
    bound = CHUNK_ROWS + int(sizes["len"].max())
    waiting = lazy.head(0).collect()
    done = 0  # drives given, in order of their last row
    for start in range(0, total, CHUNK_ROWS):
        waiting = pl.concat([waiting, lazy.slice(start, CHUNK_ROWS).collect()])
        ready = by_last["drive_id"].slice(done).filter(by_last["last"].slice(done) < start + CHUNK_ROWS)
        done += ready.len()
        if ready.len():
            if done == by_last.height:
                yield waiting
                return
            go = pl.col("drive_id").is_in(ready.implode())
            yield waiting.filter(go)
            waiting = waiting.filter(~go)
        if waiting.height > bound:
            break
    else:
        return
    del waiting
    rest = sizes.filter(pl.col("drive_id").is_in(by_last["drive_id"].slice(done).implode()))
    span = dict(zip(rest["drive_id"], zip(rest["first"], rest["last"], strict=True), strict=True))
    for chunk_ids in batches(rest.select("drive_id", "len").iter_rows(), CHUNK_ROWS):
        # only the rows between the chunk's first and last row are scanned
        first, last = min(span[d][0] for d in chunk_ids), max(span[d][1] for d in chunk_ids)
        yield lazy.slice(first, last - first + 1).filter(pl.col("drive_id").is_in(chunk_ids)).collect()


# the drives of a chunk are cast and split this many rows at a time: one cast of many drives instead of one per
# drive, without a second copy of a whole chunk
SPLIT_ROWS = 1_000_000


def _drives_at_once(rows: pl.DataFrame, drives_meta: dict[str, dict], maps: dict[str, _Parts],
                    tracks_file: str | Path, drives_file: str | Path, source_format: str) -> list[DriveData] | None:
    """What ``_drive`` gives for each drive of ``rows`` (in order of first row), with the columns cast once for
    all of them; None when a column does not convert (``_drive``, drive by drive, then says where)."""
    sizes = rows.group_by("drive_id", maintain_order=True).len()
    refused: dict[str, DriveData] = {}
    periods: dict[str, float] = {}
    derive = []
    for drive_id, n in sizes.iter_rows():
        meta = drives_meta.get(drive_id, {})
        bad = _bad_period(drive_id, meta, n, tracks_file, drives_file, source_format)
        if bad is not None:
            refused[drive_id] = bad
        elif not meta.get("dt_s"):
            derive.append(drive_id)
        else:
            periods[drive_id] = meta["dt_s"]
    if derive:  # no dt_s given: each drive's own median step of t_s
        own = rows.filter(pl.col("drive_id").is_in(derive)).partition_by("drive_id", as_dict=True)
        periods.update({drive_id: _sample_period({}, own[(drive_id,)]) for drive_id in derive})
    if refused:
        rows = rows.filter(~pl.col("drive_id").is_in(list(refused)))
    if "frame" not in rows.columns and rows.schema.get("t_s") != pl.Float64:
        return None  # t_s / dt in t_s's own type: drive by drive, as _drive divides
    period = (pl.col("drive_id").replace_strict(periods, return_dtype=pl.Float64) if periods
              else pl.lit(None, pl.Float64))  # no rows left
    rows = _completed(rows, period)
    try:
        tracks = check_table(rows, schema.TRACKS, tracks_file, REQUIRED)
    except InputError:
        return None
    del rows
    egos = dict(tracks.filter(pl.col("is_ego") & pl.col("actor_id").is_not_null())
                .group_by("drive_id").agg(pl.col("actor_id").unique().sort()).iter_rows())
    kept = sizes.filter(~pl.col("drive_id").is_in(list(refused)))
    split = by_drive(tracks, kept)
    if split is None:
        split = {d: rows for (d,), rows in tracks.partition_by("drive_id", as_dict=True, maintain_order=True).items()}
    del tracks
    out = []
    for drive_id, n in sizes.iter_rows():
        if drive_id in refused:
            out.append(refused.pop(drive_id))
        else:
            out.append(_read_drive(drive_id, split.pop(drive_id), n, periods[drive_id],
                                   drives_meta.get(drive_id, {}), maps, egos.get(drive_id, []), tracks_file,
                                   source_format))
    return out


def by_drive(rows: pl.DataFrame, sizes: pl.DataFrame) -> dict[str, pl.DataFrame] | None:
    """Each drive's rows as a slice of ``rows`` (no copy) when they are one run per drive in the order of
    ``sizes`` (drive_id, len), as logs come; None when the drives' rows are interleaved or out of that order."""
    if rows.height != sizes["len"].sum() or rows.select(
            pl.col("drive_id").ne_missing(pl.col("drive_id").shift()).sum()).item() != sizes.height:
        return None
    starts = np.cumsum(sizes["len"].to_numpy()) - sizes["len"].to_numpy()
    runs = {d: rows.slice(int(a), n) for (d, n), a in zip(sizes.iter_rows(), starts, strict=True)}
    # the runs must be the drives of ``sizes``, each once (a drive in two runs has more run starts than drives)
    return runs if all(r.height == 0 or r["drive_id"][0] == d for d, r in runs.items()) else None


class _Parts:
    """The rows of a table for one key value (an empty frame of its columns when it has none)."""

    def __init__(self, frame: pl.DataFrame, key: str):
        self.parts = frame.partition_by(key, as_dict=True, maintain_order=True)
        self.empty = frame.clear()

    def of(self, value: str) -> pl.DataFrame:
        return self.parts.get((value,), self.empty)


def _drive(drive_id: str, rows: pl.DataFrame, meta: dict, maps: dict[str, _Parts], tracks_file: str | Path,
           drives_file: str | Path, source_format: str) -> DriveData:
    bad = _bad_period(drive_id, meta, rows.height, tracks_file, drives_file, source_format)
    if bad is not None:
        return bad
    dt = _sample_period(meta, rows)
    rows = _completed(rows, dt)
    tracks = check_table(rows, schema.TRACKS, tracks_file, REQUIRED)
    egos = tracks.filter(pl.col("is_ego") & pl.col("actor_id").is_not_null())["actor_id"].unique().sort().to_list()
    return _read_drive(drive_id, tracks, rows.height, dt, meta, maps, egos, tracks_file, source_format)


def _completed(rows: pl.DataFrame, period: float | pl.Expr) -> pl.DataFrame:
    """The optional columns a file may leave out: frame from t_s and the sample period, is_ego false."""
    if "frame" not in rows.columns:
        # a time too large for a frame number becomes NULL here and is dropped, counted, at ingest
        rows = rows.with_columns(frame=(pl.col("t_s") / period).round().cast(pl.Int64, strict=False))
    if "is_ego" not in rows.columns:
        rows = rows.with_columns(is_ego=pl.lit(False))
    return rows


def _bad_period(drive_id: str, meta: dict, rows_read: int, tracks_file: str | Path, drives_file: str | Path,
                source_format: str) -> DriveData | None:
    """The drive rejected, when drives.parquet gives it a dt_s that is not a positive number."""
    dt = meta.get("dt_s")
    if dt is not None and not (math.isfinite(dt) and dt > 0):
        return DriveData(drive_id=drive_id, source_format=source_format, source_path=str(tracks_file), dt_s=math.nan,
                         tracks=pl.DataFrame(), map_id=meta.get("map_id"), rows_read=rows_read,
                         reject_reason=f"{drives_file}: drive '{drive_id}' has dt_s = "
                                       f"{dt}. Fix: write the sample period in seconds (> 0), or leave it NULL to "
                                       "derive it from t_s.")
    return None


def _sample_period(meta: dict, rows: pl.DataFrame) -> float:
    """dt_s as drives.parquet gives it, else the median step of the drive's t_s (0.1 when it has none)."""
    dt = meta.get("dt_s")
    if not dt:
        steps = rows.select(pl.col("t_s").filter(pl.col("t_s").is_finite()).unique().sort().diff().drop_nulls())
        dt = float(steps["t_s"].median()) if steps.height else None
    return dt if dt and dt > 0 else 0.1


def _read_drive(drive_id: str, tracks: pl.DataFrame, rows_read: int, dt: float, meta: dict, maps: dict[str, _Parts],
                egos: list[str], tracks_file: str | Path, source_format: str) -> DriveData:
    """The drive of its cast rows (``egos``: the actor ids with is_ego = true, sorted)."""
    map_id = meta.get("map_id")
    drive = DriveData(drive_id=drive_id, source_format=source_format, source_path=str(tracks_file), dt_s=dt,
                      tracks=tracks, map_id=map_id, rows_read=rows_read, attribution=meta.get("attribution"))
    if len(egos) > 1:
        drive.tracks = tracks.clear()
        drive.reject_reason = (f"{tracks_file}: drive '{drive_id}' has {len(egos)} actors with is_ego = true "
                               f"({', '.join(egos[:5])}); a drive has at most one recorded ego.")
        return drive
    drive.ego_actor_id = egos[0] if egos else meta.get("ego_actor_id")
    if map_id:
        for name in schema.MAP_TABLE_NAMES:
            if name in maps:
                setattr(drive, name, maps[name].of(map_id))
    if "traffic_light_states" in maps:
        drive.traffic_light_states = maps["traffic_light_states"].of(drive_id)
    return drive
