"""Exports of matches and drives into standard formats: OpenSCENARIO (``xosc``) and ASAM OpenLABEL (``openlabel``).

The mappings are documented in docs/formats.md; the published schemas the outputs are valid against are in
``logiq_sql/outputs/schemas/`` with their licences.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import duckdb

from logiq_sql.core.errors import InputError
from logiq_sql.storage import db

SCHEMAS = Path(__file__).resolve().parent.parent / "schemas"
OPENSCENARIO_XSD = SCHEMAS / "OpenSCENARIO_1_3_1.xsd"
OPENLABEL_SCHEMA = SCHEMAS / "openlabel_json_schema-v1.0.0.json"


def open_db(path: str | Path) -> duckdb.DuckDBPyConnection:
    """The DuckDB file, read-only; a clear error when it is not there or was written by an earlier logiq_sql."""
    if not Path(path).is_file():
        raise InputError(f"--db {path}: no such file (write one with `logiq-sql ingest` and `logiq-sql match`).")
    return db.open_current(path)


def xodr_file(map_id: str | None, source_path: str) -> Path | None:
    """The OpenDRIVE file a drive's map was read from: the ``.xodr`` beside its source whose content gives the
    map_id (``xodr-`` + SHA-1), or None (not an OpenDRIVE map, or the file moved or changed)."""
    if not map_id or not map_id.startswith("xodr-"):
        return None
    source = Path(source_path)
    for candidate in sorted((source if source.is_dir() else source.parent).glob("*.xodr")):
        if "xodr-" + hashlib.sha1(candidate.read_bytes()).hexdigest()[:16] == map_id:
            return candidate
    return None
