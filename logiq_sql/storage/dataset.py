"""A dataset: the canonical input tables as Parquet folders, the interchange between machines.

Layout (one folder per table, hive partitions, so Spark and DuckDB read only the drives or maps they need):

    DIR/<table>/drive_id=<id>/<part>-<i>.parquet   tracks, track_lanes, traffic_light_states, drive_inputs
    DIR/<table>/map_id=<id>/map-<i>.parquet         lanes, lane_successors, junctions, traffic_lights

``ingest FORMAT PATHS --dataset DIR`` (logiq_sql/ingestion/dataset_ingest.py) reads each input file on its own (the
ordinary ingest into a temporary DuckDB file, localisation included), then writes its tables under a part name
made from the file's path: many machines can ingest different files into one DIR at the same time without
writing the same file. A drive that is ingested again replaces its folders. A map is written under a fixed name
per map id: a map written again (the same map, as ingest assumes for one map_id) replaces its files.

``attach(con, DIR)`` makes the canonical tables of a DuckDB file views over a dataset, so the matcher (and an
analyst) reads it as it reads an ingested file; the Spark engine reads DIR itself.
"""

from __future__ import annotations

import hashlib
import shutil
import urllib.parse
from pathlib import Path

import duckdb

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError, arg
from logiq_sql.core.sql import sql_literal

INPUT_TABLES = (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES)
MARKER = "_logiq_sql_dataset"  # written at the top of a dataset: what attach and --engine spark check


def partition_key(table: schema.Table) -> str:
    return "drive_id" if table.name in schema.DRIVE_TABLE_NAMES else "map_id"


def partitions(folder: Path, key: str, value: str) -> list[Path]:
    """The existing folders of ``key=value`` under ``folder`` (DuckDB percent-encodes characters such as ``@``)."""
    if not folder.is_dir():
        return []
    return [p for p in folder.iterdir() if p.is_dir() and p.name.startswith(f"{key}=")
            and urllib.parse.unquote(p.name.split("=", 1)[1]) == value]


def is_dataset(folder: str | Path) -> bool:
    return (Path(folder) / MARKER).is_file()



def write(con: duckdb.DuckDBPyConnection, folder: str | Path, part: str) -> Path:
    """Add the canonical tables of ``con`` to the dataset ``folder`` under the file name ``part``: the drives it
    holds replace their earlier folders; its maps replace theirs."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / MARKER).write_text("logiq_sql dataset: canonical tables as Parquet, partitioned by drive_id or "
                                 "map_id (logiq_sql/storage/dataset.py)\n")
    drives = [r[0] for r in con.execute("select drive_id from drive_inputs").fetchall()]
    for table in INPUT_TABLES:
        key = partition_key(table)
        target = folder / table.name
        target.mkdir(exist_ok=True)
        if key == "drive_id":
            for drive in drives:  # a drive ingested again replaces its rows, whichever part held them
                for old in partitions(target, key, drive):
                    shutil.rmtree(old)
        if not con.execute(f"select count(*) from {table.name}").fetchone()[0]:
            continue
        pattern = f"{part}-{{i}}" if key == "drive_id" else "map-{i}"
        con.execute(f"copy (select {', '.join(table.column_names)} from {table.name}) to {sql_literal(str(target))} "
                    f"(format parquet, partition_by ({key}), filename_pattern '{pattern}', overwrite_or_ignore)")
    return folder


def part_name(source: Path) -> str:
    """The file name of an input file's parts: the same for the same file, whichever machine ingests it."""
    return "part-" + hashlib.sha1(str(source.resolve()).encode()).hexdigest()[:16]


def attach(con: duckdb.DuckDBPyConnection, folder: str | Path) -> None:
    """Make the canonical input tables of the DuckDB file ``con`` views over the dataset ``folder`` (absolute
    paths, so the file can be opened from anywhere that sees the folder). Refuses a file that holds ingested
    rows: they would be hidden."""
    folder = Path(folder).resolve()
    if not is_dataset(folder):
        raise InputError(f"{arg('dataset', folder)}: not a logiq_sql dataset (no {MARKER} file); write one with "
                         "`logiq-sql ingest FORMAT PATHS --dataset DIR`.")
    kinds = dict(con.execute("select table_name, 'table' from duckdb_tables() where schema_name = 'main' and "
                             "database_name = current_database()").fetchall())
    for table in INPUT_TABLES:
        if kinds.get(table.name) == "table":
            if con.execute(f"select count(*) from main.{table.name}").fetchone()[0]:
                raise InputError(f"{arg('dataset', folder)}: the results file already holds ingested rows in "
                                 f"{table.name}; give a new results file for a dataset.")
            con.execute(f"drop table main.{table.name}")
        files = folder / table.name
        cols = ", ".join(table.column_names)
        if any(files.rglob("*.parquet")):
            source = (f"read_parquet({sql_literal(str(files) + '/**/*.parquet')}, hive_partitioning = true, "
                      f"hive_types = {{'{partition_key(table)}': varchar}})")
            have = {r[0] for r in con.execute(f"describe select * from {source}").fetchall()}
            if missing := [c for c in table.column_names if c not in have]:
                raise InputError(f"{arg('dataset', folder)}: {table.name} has no column {', '.join(missing)}: the "
                                 "dataset was written by an earlier logiq_sql. Fix: ingest its inputs again with "
                                 "`logiq-sql ingest FORMAT PATHS --dataset DIR` into a new folder.")
        else:  # nothing of this table yet (no traffic lights, say): an empty view of the right columns
            source = ("(select " + ", ".join(f"cast(null as {schema.duckdb_type(c.dtype)}) as {c.name}"
                                            for c in table.columns) + " where false)")
        con.execute(f"create or replace view main.{table.name} as select {cols} from {source}")
        con.execute(f"comment on view main.{table.name} is {sql_literal(table.doc + ' (a view over ' + str(files) + ')')}")
        for c in table.columns:
            con.execute(f"comment on column main.{table.name}.{c.name} is {sql_literal(c.doc)}")
