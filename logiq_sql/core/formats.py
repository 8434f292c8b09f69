"""The source formats ``ingest`` reads, declared once: the CLI's choices and help, the ``source_format`` column's
documentation and how ``ingest`` expands a folder all come from this table. Each format's reader is the module
``logiq_sql/ingestion/readers/<name>.py`` with its function ``read_<name>`` (docs/formats.md)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SourceFormat:
    name: str
    help: str  # what the format is, for --help
    suffixes: tuple[str, ...] = ()  # the files a folder given as a path is searched for
    folders: str | None = None  # else: the reader module's function that lists the drives' folders in a folder
    drive_folder_marker: str | None = None  # a folder holding this file is itself one drive


FORMATS: dict[str, SourceFormat] = {f.name: f for f in (
    SourceFormat("commonroad", "CommonRoad XML (.xml, .xml.gz)", suffixes=(".xml", ".xml.gz")),
    SourceFormat("scenarionet", "ScenarioNet .pkl", suffixes=(".pkl",)),
    SourceFormat("parquet", "canonical tables (see docs/tables.md)", suffixes=(".parquet",),
                 drive_folder_marker="tracks.parquet"),
    SourceFormat("sumo", "SUMO run folders (docs/sumo.md)", folders="run_folders"),
    SourceFormat("av2", "Argoverse 2 sensor-log and motion-forecasting folders", folders="log_folders"),
    SourceFormat("opendrive", "an .xodr map with tracks.parquet beside it", suffixes=(".xodr",)),
    SourceFormat("osi", "ASAM OSI traces (.osi, .mcap), with an .xodr beside them as the map",
                 suffixes=(".osi", ".mcap")),
)}


def formats_help() -> str:
    """Every format with what it is: the help of ``logiq-sql ingest FORMAT``."""
    return "; ".join(f"{f.name}: {f.help}" for f in FORMATS.values()) + " (docs/formats.md)"
