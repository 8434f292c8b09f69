"""The source formats ``ingest`` reads, declared once: the CLI's choices and help, the ``source_format`` column's
documentation, the table of formats in docs/formats.md (``make docs``) and how ``ingest`` expands a folder all come
from this table. Each format's reader is the module
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
    found: str | None = None  # with ``folders``: what that function finds, for docs/formats.md


FORMATS: dict[str, SourceFormat] = {f.name: f for f in (
    SourceFormat("commonroad", "CommonRoad XML (.xml, .xml.gz)", suffixes=(".xml", ".xml.gz")),
    SourceFormat("scenarionet", "ScenarioNet .pkl", suffixes=(".pkl",)),
    SourceFormat("parquet", "canonical tables (see docs/tables.md)", suffixes=(".parquet",),
                 drive_folder_marker="tracks.parquet"),
    SourceFormat("sumo", "SUMO run folders (docs/sumo.md)", folders="run_folders",
                 found="folders holding a `.sumocfg`, a network or an FCD output, found by content whatever the "
                       "files are named"),
    SourceFormat("av2", "Argoverse 2 sensor-log and motion-forecasting folders", folders="log_folders",
                 found="log and scenario folders: those holding `city_SE3_egovehicle.feather`, "
                       "`annotations*.feather` or `scenario_*.parquet`"),
    SourceFormat("opendrive", "an .xodr map with tracks.parquet beside it", suffixes=(".xodr",)),
    SourceFormat("osi", "ASAM OSI traces (.osi, .mcap), with an .xodr beside them as the map",
                 suffixes=(".osi", ".mcap")),
)}


def formats_help() -> str:
    """Every format with what it is: the help of ``logiq-sql ingest FORMAT``."""
    return "; ".join(f"{f.name}: {f.help}" for f in FORMATS.values()) + " (docs/formats.md)"


def _path_expands(f: SourceFormat) -> str:
    """What ``ingest`` reads for a PATH given on its command line (``ingestion.ingest.expand``)."""
    if f.folders:
        return f"the drive folders at or under it ({f.found}); a file means its folder"
    files = " or ".join(f"`{suffix}`" for suffix in f.suffixes)
    if f.drive_folder_marker:
        return (f"a file, or a folder holding `{f.drive_folder_marker}`, as it is; another folder: every file under "
                f"it ending in {files}, in path order")
    return f"a file as it is; a folder: every file under it ending in {files}, in path order"


def formats_markdown() -> str:
    """The table of formats in docs/formats.md (``make docs``)."""
    out = ["| format | what it is | a PATH of `ingest FORMAT PATH...` | reader |", "|---|---|---|---|"]
    out += [f"| `{f.name}` | {f.help} | {_path_expands(f)} | `logiq_sql/ingestion/readers/{f.name}.py` |"
            for f in FORMATS.values()]
    return "\n".join(out)
