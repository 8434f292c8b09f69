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

from pathlib import Path

import polars as pl

from logiq_sql import schema
from logiq_sql.errors import InputError, did_you_mean
from logiq_sql.readers.base import DriveData

REQUIRED = ("drive_id", "actor_id", "kind", "t_s", "x_m", "y_m")
_NUMERIC = ("t_s", "x_m", "y_m", "heading_rad", "speed_mps", "accel_mps2", "length_m", "width_m")


def _read(path: Path) -> pl.DataFrame:
    try:
        return pl.read_parquet(path)
    except Exception as exc:  # polars raises several types for corrupt files
        raise InputError(f"{path}: not a readable Parquet file ({type(exc).__name__}: {exc}).") from None


def _check_columns(frame: pl.DataFrame, table: schema.Table, required: tuple[str, ...], path: Path) -> pl.DataFrame:
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
            out.append(pl.col(c.name).cast(c.dtype, strict=True))
        except Exception:  # pragma: no cover - cast errors surface at select time
            raise
    try:
        return frame.select(out)
    except pl.exceptions.InvalidOperationError as exc:
        raise InputError(f"{path}: a column has the wrong type ({exc}).\n\nHint: see docs/tables.md.") from None


def read_parquet(path: str | Path) -> list[DriveData]:
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    tracks_file = path / "tracks.parquet" if path.is_dir() else path
    raw = _read(tracks_file)
    unknown = [c for c in raw.columns if c not in schema.TRACKS.column_names]
    for col in REQUIRED:
        if col not in raw.columns:
            raise InputError(
                f"{tracks_file}: missing column '{col}'.{did_you_mean(col, unknown, cutoff=0.5)}\n\n"
                f"Hint: tracks need {', '.join(REQUIRED)}; see docs/tables.md."
            )
    for col in _NUMERIC:
        if col in raw.columns and not raw.schema[col].is_numeric():
            raise InputError(
                f"{tracks_file}: column '{col}' is {raw.schema[col]}, not a number.\n\n"
                f"Hint: write {col} as a float in the unit its name says."
            )
    drives_meta: dict[str, dict] = {}
    if path.is_dir() and (folder / "drives.parquet").exists():
        drives_meta = {r["drive_id"]: r for r in _read(folder / "drives.parquet").to_dicts()}
    maps = {t.name: _check_columns(_read(folder / f"{t.name}.parquet"), t,
                                   tuple(c.name for c in t.columns if not c.nullable), folder / f"{t.name}.parquet")
            for t in (*schema.MAP_TABLES, schema.TRAFFIC_LIGHT_STATES)
            if path.is_dir() and (folder / f"{t.name}.parquet").exists()}

    out = []
    for (drive_id,), rows in raw.group_by("drive_id", maintain_order=True):
        meta = drives_meta.get(str(drive_id), {})
        if not rows["t_s"].is_finite().all():
            dt = None
        else:
            steps = rows.select(pl.col("t_s").unique().sort().diff().drop_nulls())["t_s"]
            dt = meta.get("dt_s") or (float(steps.median()) if len(steps) else 0.1)
        if not dt or dt <= 0:
            dt = 0.1
        rows = rows.with_columns(pl.col("drive_id").cast(pl.String), pl.col("actor_id").cast(pl.String))
        if "frame" not in rows.columns:
            rows = rows.with_columns(frame=(pl.col("t_s") / dt).round().cast(pl.Int64))
        if "is_ego" not in rows.columns:
            rows = rows.with_columns(is_ego=pl.lit(False))
        tracks = _check_columns(rows, schema.TRACKS, REQUIRED, tracks_file)
        egos = tracks.filter(pl.col("is_ego"))["actor_id"].unique().to_list()
        if len(egos) > 1:
            raise InputError(f"{tracks_file}: drive '{drive_id}' has {len(egos)} actors with is_ego = true "
                             f"({', '.join(sorted(egos)[:5])}); a drive has at most one recorded ego.")
        map_id = meta.get("map_id")
        sel = (lambda t: maps[t].filter(pl.col("map_id") == map_id)) if map_id else None
        drive = DriveData(
            drive_id=str(drive_id), source_format="parquet", source_path=str(tracks_file), dt_s=dt,
            tracks=tracks, map_id=map_id, ego_actor_id=egos[0] if egos else meta.get("ego_actor_id"),
            rows_read=rows.height, attribution=meta.get("attribution"),
        )
        if sel is not None:
            for name in ("lanes", "lane_successors", "junctions", "traffic_lights"):
                if name in maps:
                    setattr(drive, name, sel(name))
        if "traffic_light_states" in maps:
            drive.traffic_light_states = maps["traffic_light_states"].filter(pl.col("drive_id") == str(drive_id))
        out.append(drive)
    return out
