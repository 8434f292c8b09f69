"""ASAM OpenDRIVE maps (``.xodr``) with tracks in the map's frame.

``ingest opendrive PATH``: PATH is an ``.xodr`` file, or a folder searched for them; beside each map lie its drives
as canonical Parquet (``tracks.parquet``, optionally ``drives.parquet`` and ``traffic_light_states.parquet``;
docs/tables.md), positions in the map's own x/y frame. Every drive of that folder gets the map. ASAM OSI traces
find a map the same way (``logiq_sql.ingestion.readers.osi``).

Map
    Converted by Eclipse SUMO's ``netconvert`` (the ``[sumo]`` extra, pinned) into a SUMO network, then read
    exactly as a SUMO run's network (``logiq_sql.ingestion.readers.sumo``: lanes with their junction-internal lanes,
    neighbours, successors with turns, junctions, one light per controlled link). netconvert options:
    ``--offset.disable-normalization`` (keep the OpenDRIVE coordinates instead of moving the map's corner to
    0,0) and ``--opendrive.internal-shapes`` (junction lanes follow the OpenDRIVE connecting roads' geometry, not
    a curve netconvert draws). Any offset netconvert still applies (``<location netOffset>``) is subtracted from
    every coordinate, so lanes stay in the frame of the tracks. Lane ids are netconvert's (``{road}.{s}_{i}``,
    internal lanes ``:{junction}_{n}_{i}``); map_id = ``xodr-`` + 16 hex digits of the SHA-1 of the file.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import polars as pl

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.base import DriveData
from logiq_sql.ingestion.readers.parquet import read_parquet
from logiq_sql.ingestion.readers.sumo import network_tables, sumo_bin

NETCONVERT_OPTIONS = ("--offset.disable-normalization", "true", "--opendrive.internal-shapes", "true",
                      "--no-turnarounds", "true", "--opposites.guess", "true")
_MAPS: dict[str, tuple[pl.DataFrame, ...]] = {}  # map_id -> tables: one conversion per map and process


def xodr_map(path: Path) -> tuple[str, tuple[pl.DataFrame, ...]]:
    """map_id and (lanes, lane_successors, junctions, traffic_lights) of an OpenDRIVE file."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: not readable ({exc}).") from None
    if b"<OpenDRIVE" not in raw[:4096]:
        raise InputError(f"{path}: no <OpenDRIVE> root element; not an OpenDRIVE map.")
    map_id = "xodr-" + hashlib.sha1(raw).hexdigest()[:16]
    if map_id not in _MAPS:
        _MAPS[map_id] = _convert(path, map_id)
    return map_id, _MAPS[map_id]


def _convert(path: Path, map_id: str) -> tuple[pl.DataFrame, ...]:
    with tempfile.TemporaryDirectory(prefix="logiq_xodr_") as tmp:
        net = Path(tmp) / "map.net.xml"
        netconvert(["--opendrive-files", str(path.resolve()), "--output-file", str(net), *NETCONVERT_OPTIONS], path,
                   "convert the OpenDRIVE map", "check the map with an OpenDRIVE validator.")
        return network_tables(net, map_id, undo_offset=True)


def netconvert(args: list[str], source: Path, what: str, fix: str) -> None:
    """Run SUMO's netconvert; its errors become an InputError naming ``source``."""
    bin_dir = sumo_bin()
    # SUMO_HOME set: netconvert finds its own type maps and stays quiet about them
    env = {**os.environ, "SUMO_HOME": str(bin_dir.parent)}
    proc = subprocess.run([str(bin_dir / "netconvert"), *args], capture_output=True, text=True, check=False, env=env)
    errors = [line for line in proc.stderr.splitlines() if line.startswith("Error")]
    if proc.returncode != 0 or errors:
        tail = "\n".join((errors or proc.stderr.splitlines())[-5:])
        raise InputError(f"{source}: netconvert could not {what} (exit code {proc.returncode}):\n{tail}\nFix: {fix}")


def with_map(drive: DriveData, map_id: str, tables: tuple[pl.DataFrame, ...]) -> DriveData:
    """The drive on this map (its map tables replaced)."""
    lanes, successors, junctions, lights = tables
    return dataclasses.replace(drive, map_id=map_id, lanes=lanes, lane_successors=successors, junctions=junctions,
                               traffic_lights=lights)


def read_opendrive(path: str | Path) -> Iterator[DriveData]:
    """The drives of the ``tracks.parquet`` beside an OpenDRIVE map, each on that map."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    maps = sorted(folder.glob("*.xodr"))
    if len(maps) != 1:
        raise InputError(f"{folder}: {len(maps)} OpenDRIVE maps (*.xodr); a folder holds one map and the "
                         "tracks.parquet of its drives. Fix: move each map and its tracks.parquet into a folder.")
    path = maps[0]
    if not (folder / "tracks.parquet").is_file():
        raise InputError(f"{path}: no tracks.parquet beside the map. Fix: write the drives' tracks in the map's "
                         "frame as canonical Parquet (docs/tables.md) into " + str(folder / "tracks.parquet") + ".")
    clash = [t.name for t in schema.MAP_TABLES if (folder / f"{t.name}.parquet").exists()]
    if clash:
        raise InputError(f"{folder}: both an OpenDRIVE map and {', '.join(f'{c}.parquet' for c in clash)}; a drive "
                         "has one map. Fix: remove the map tables or ingest the folder with `ingest parquet`.")
    map_id, tables = xodr_map(path)
    for drive in read_parquet(folder):
        yield dataclasses.replace(with_map(drive, map_id, tables), source_format="opendrive")
