"""Engines that run the query files: DuckDB (the reference), Spark and Polars SQL.

The matcher (``logiq_sql/match.py``) orchestrates the steps; an engine only executes them:

    materialise(table, relative, values)   run queries/<relative> with its parameters bound, keep it as <table>
    frame(sql)                             a query (DuckDB dialect) or a table name -> Polars frame
    register(table, frame)                 make a Polars frame a table the next steps can read
    persist(tables)                        copy the named step tables into the DuckDB file's temp schema, where
                                           the matcher stores them from, and forget them (a no-op for DuckDB)

Every engine reads the same ``queries/`` text, written in DuckDB dialect. Parameters stay bound: DuckDB binds
``$name`` natively, Spark gets the sqlglot transpile with ``:name`` markers and ``args=``, and Polars SQL (which
has no placeholders) gets literals put into the sqlglot tree, never into the text. Decisions, the per-query
Polars verdicts and how to run on a Spark cluster: docs/engines.md.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
import tempfile
from pathlib import Path

import duckdb
import polars as pl
import sqlglot
from sqlglot import exp

from logiq_sql import schema
from logiq_sql.errors import LogiqError
from logiq_sql.sql import sql_literal, used_values, bind, materialise, query_text

ENGINES = ("duckdb", "spark", "polars")
SPARK_MASTER_ENV = "SPARK_MASTER"
DEFAULT_SPARK_MASTER = "local[2]"
# the canonical tables a match reads; Spark's Parquet copies of the per-drive ones are partitioned by drive_id
INPUT_TABLES = (*schema.ALL_INPUT_TABLES, schema.TRACK_LANES)
PARTITIONED_BY_DRIVE = ("tracks", "track_lanes", "traffic_light_states")


class EngineError(LogiqError):
    """An engine is not installed, or cannot run a query."""


def as_engine(con_or_engine: duckdb.DuckDBPyConnection | Engine) -> Engine:
    """Callers that hold a DuckDB connection (explain, tests) keep passing it; the matcher passes an engine."""
    if isinstance(con_or_engine, duckdb.DuckDBPyConnection):
        return DuckEngine(con_or_engine)
    return con_or_engine


class Engine:
    """What the matcher needs from an engine (module docstring); DuckEngine is the reference."""

    name = "engine"

    def materialise(self, table: str, relative: str, values: dict[str, object]) -> None:
        raise NotImplementedError

    def frame(self, sql: str) -> pl.DataFrame:
        raise NotImplementedError

    def register(self, table: str, frame: pl.DataFrame) -> None:
        raise NotImplementedError

    def select_drives(self) -> None:
        """From now on the per-drive input tables hold only the drives of ``run_drives`` (the batch)."""

    def release_drives(self) -> None:
        """Undo ``select_drives``."""

    def persist(self, tables: tuple[str, ...]) -> None:
        """Copy the step tables among ``tables`` that this group made into DuckDB temp tables, then forget them."""

    def close(self) -> None:
        """Release what the engine holds (Spark views, exported Parquet)."""


class DuckEngine(Engine):
    """The reference: every step is a temp table of the DuckDB file's connection."""

    name = "duckdb"

    def __init__(self, con: duckdb.DuckDBPyConnection):
        self.con = con

    def materialise(self, table: str, relative: str, values: dict[str, object]) -> None:
        materialise(self.con, table, relative, values)

    def frame(self, sql: str) -> pl.DataFrame:
        return self.con.sql(_as_query(sql)).pl()

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.con.register(f"_{table}", frame)
        self.con.execute(f"create or replace temp table {table} as select * from _{table}")
        self.con.unregister(f"_{table}")

    def select_drives(self) -> None:
        # a temp table shadows the stored table of the same name, so every query of the batch reads the batch's
        # rows: a batch then costs what its drives hold, not what the whole file holds (at 10 M rows, queries
        # reading the whole track_lanes per batch made matching grow with batches x file size)
        stored = stored_schema(self.con)
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"create or replace temp table {table} as select * from {stored}.{table} "
                             "where drive_id in (select drive_id from run_drives)")

    def release_drives(self) -> None:
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"drop table if exists temp.main.{table}")


def stored_schema(con: duckdb.DuckDBPyConnection) -> str:
    """The DuckDB file's own schema, quoted: names in it stay reachable while a temp table shadows them."""
    return '"' + con.execute("select current_database()").fetchall()[0][0].replace('"', '""') + '".main'


def _as_query(sql: str) -> str:
    return f"select * from {sql}" if re.fullmatch(r"\w+", sql) else sql


def _copy_into_duckdb(con: duckdb.DuckDBPyConnection, table: str, frame: pl.DataFrame) -> None:
    con.register("_engine_copy", frame)
    con.execute(f"create or replace temp table {table} as select * from _engine_copy")
    con.unregister("_engine_copy")


# ---------------------------------------------------------------------------------------------------- Spark


@functools.cache
def spark_text(relative: str) -> str:
    """queries/<relative> in Spark SQL: sqlglot's DuckDB -> Spark transpile; ``$name`` becomes ``:name``."""
    return sqlglot.transpile(query_text(relative), read="duckdb", write="spark", pretty=True)[0]


def spark_type(dtype: pl.DataType | type[pl.DataType]):
    from pyspark.sql import types as T

    spark_types = {pl.String: T.StringType, pl.Float64: T.DoubleType, pl.Int64: T.LongType, pl.Boolean: T.BooleanType}
    return spark_types[dtype if isinstance(dtype, type) else type(dtype)]()


def spark_session(master: str | None = None):
    """The active Spark session, or a new one on ``master`` (else $SPARK_MASTER, else spark-submit's --master, else
    local[2])."""
    try:
        from pyspark.sql import SparkSession
    except ImportError:
        raise EngineError("--engine spark needs PySpark and Java 17: pip install 'logiq-sql[spark]'.") from None
    active = SparkSession.getActiveSession()
    if active is not None:
        return active
    builder = SparkSession.builder
    master = master or os.environ.get(SPARK_MASTER_ENV)
    if master or "PYSPARK_GATEWAY_PORT" not in os.environ:  # under spark-submit, its --master applies
        builder = builder.master(master or DEFAULT_SPARK_MASTER)
    session = (builder.appName("logiq-sql")
               .config("spark.ui.enabled", "false")
               .config("spark.ui.showConsoleProgress", "false")
               .config("spark.sql.shuffle.partitions", "4")
               .config("spark.sql.session.timeZone", "UTC")
               # drive ids such as '101' stay strings when read back from partition folder names
               .config("spark.sql.sources.partitionColumnTypeInference.enabled", "false")
               .getOrCreate())
    session.sparkContext.setLogLevel("ERROR")  # Spark's own warnings would drown logiq-sql's progress lines
    return session


def export_parquet(con: duckdb.DuckDBPyConnection, folder: str | Path) -> Path:
    """The canonical input tables of a DuckDB file as Parquet folders ``<folder>/<table>/``; per-drive tables
    partitioned by drive_id (``drive_id=<id>/``), so a cluster reads only the drives it is given."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for table in INPUT_TABLES:
        target = folder / table.name
        if target.exists():
            shutil.rmtree(target)
        target.mkdir()
        cols = ", ".join(table.column_names)
        options = "format parquet" + (", partition_by (drive_id)" if table.name in PARTITIONED_BY_DRIVE else "")
        path = str(target) if table.name in PARTITIONED_BY_DRIVE else str(target / "part-0.parquet")
        if con.execute(f"select count(*) from {table.name}").fetchone()[0]:
            con.execute(f"copy (select {cols} from {table.name}) to '{_sql_string(path)}' ({options})")
    return folder


def _sql_string(text: str) -> str:
    return text.replace("'", "''")


class SparkEngine(Engine):
    """Steps run with ``spark.sql(text, args=...)`` over the canonical tables as Parquet; each step's result is
    checkpointed (computed once, lineage cut) and kept as a temp view of the step's name."""

    name = "spark"

    def __init__(self, con: duckdb.DuckDBPyConnection, master: str | None = None, tables: str | None = None):
        self.con = con
        self.spark = spark_session(master)
        self.views: dict[str, object] = {}
        self.inputs: dict[str, object] = {}
        self.own_folder = tables is None
        self.folder = Path(tempfile.mkdtemp(prefix="logiq_sql_spark_")) if tables is None else Path(tables)
        export_parquet(con, self.folder)
        for table in INPUT_TABLES:
            self._read_input(table)

    def _read_input(self, table: schema.Table) -> None:
        from pyspark.sql import types as T

        struct = T.StructType([T.StructField(c.name, spark_type(c.dtype), True) for c in table.columns])
        path = self.folder / table.name
        if any(path.rglob("*.parquet")):
            df = self.spark.read.schema(struct).parquet(str(path)).select(*table.column_names)
        else:
            df = self.spark.createDataFrame([], struct)
        self.inputs[table.name] = df
        df.createOrReplaceTempView(table.name)

    def _keep(self, table: str, df) -> None:
        old = self.views.pop(table, None)
        df = df.localCheckpoint(eager=True)  # later steps read it many times; plans stay short
        df.createOrReplaceTempView(table)
        self.views[table] = df
        if old is not None:
            old.unpersist()

    def materialise(self, table: str, relative: str, values: dict[str, object]) -> None:
        self._keep(table, self.spark.sql(spark_text(relative), args=bind(relative, values)))

    def frame(self, sql: str) -> pl.DataFrame:
        text = sqlglot.transpile(_as_query(sql), read="duckdb", write="spark")[0]
        return pl.from_arrow(self.spark.sql(text).toArrow())

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self._keep(table, self.spark.createDataFrame(frame.to_arrow(compat_level=pl.CompatLevel.oldest())))

    def select_drives(self) -> None:
        # the Parquet is partitioned by drive_id: a semi join with the batch's drives reads only their folders
        batch = self.views["run_drives"]
        for table in PARTITIONED_BY_DRIVE:
            self.inputs[table].join(batch, "drive_id", "left_semi").createOrReplaceTempView(table)

    def release_drives(self) -> None:
        for table in PARTITIONED_BY_DRIVE:
            self.inputs[table].createOrReplaceTempView(table)

    def persist(self, tables: tuple[str, ...]) -> None:
        for table in tables:
            if table in self.views:
                _copy_into_duckdb(self.con, table, self.frame(table))
                # the next group of the run keeps only what it computes itself
                self.views.pop(table).unpersist()
                self.spark.catalog.dropTempView(table)

    def close(self) -> None:
        for df in self.views.values():
            df.unpersist()
        for name in (*self.views, *(t.name for t in INPUT_TABLES)):
            self.spark.catalog.dropTempView(name)
        self.views.clear()
        if self.own_folder:
            shutil.rmtree(self.folder, ignore_errors=True)


def check_engine(name: str, relatives: list[str]) -> None:
    """Raise before anything runs if a query of the run cannot run on engine ``name``."""
    if name not in ENGINES:
        raise EngineError(f"--engine {name}: choose one of {', '.join(ENGINES)}.")
    for rel in relatives:
        if name == "polars" and rel in POLARS_UNSUPPORTED:
            raise EngineError(f"--engine polars: queries/{rel} cannot run on Polars SQL: {POLARS_UNSUPPORTED[rel]}. "
                              "Run this scenario with --engine duckdb or spark (docs/engines.md: what runs where).")


def render_spark_steps(steps: list[tuple[str, str]], values: dict[str, object]) -> tuple[str, dict[str, object]]:
    """The steps as one Spark SQL statement, each step's own transpile (what the Spark engine runs) nested as a CTE,
    so the CTE names inside different query files stay apart; and the values to bind with ``args=``."""
    def indented(text: str) -> str:
        return "\n".join("  " + line if line else "" for line in text.splitlines())

    ctes = [f"{name} AS (\n{indented(spark_text(rel))}\n)" for name, rel in steps[:-1]]
    text = "WITH\n" + ",\n".join(ctes) + "\nSELECT * FROM (\n" + indented(spark_text(steps[-1][1])) + "\n)"
    return text, used_values(steps, values)


def render_for_engine(name: str, s, steps: list[tuple[str, str]], values: dict[str, object]) -> str:
    """``render --engine spark``: the scenario's CTE chain in Spark SQL, headed by the values to bind as comments
    and the call that binds them. The values are never part of the SQL text."""
    if name != "spark":
        raise EngineError(f"render --engine {name}: render prints DuckDB (default) or Spark SQL; Polars SQL has no "
                          "parameters, so there is no bound statement to print.")
    text, args = render_spark_steps(steps, values)
    header = [f"-- scenario {s.name} (version {s.version}), params_hash {s.params_hash()}, Spark SQL",
              "-- bind the parameters, never format them in:  spark.sql(text, args={...the values below...})"]
    header += [f"-- :{name} = {sql_literal(value)}" for name, value in args.items()]
    header += ["-- reads the canonical tables (docs/tables.md) and run_drives (drive_id of the drives to match) as "
               "tables or temp views" + ("; encroachments (shapely) as stored by a match" if s.junctions else "")]
    if s.junctions:
        header.append("-- Spark 4.3's analyser gives up on this statement as one piece (Max iterations (100) reached "
                      "for batch Resolution): run it step by step, as match --engine spark does (docs/engines.md)")
    return "\n".join(header) + "\n" + text + "\n"


def open_engine(name: str, con: duckdb.DuckDBPyConnection, spark_master: str | None = None,
                spark_tables: str | None = None) -> Engine:
    if name == "duckdb":
        return DuckEngine(con)
    if name == "spark":
        return SparkEngine(con, spark_master, spark_tables)
    if name == "polars":
        return PolarsEngine(con)
    raise EngineError(f"--engine {name}: choose one of {', '.join(ENGINES)}.")


# --------------------------------------------------------------------------------------------------- Polars


def inline_parameters(relative: str, values: dict[str, object]) -> str:
    """queries/<relative> with every ``$name`` replaced by its value as a literal node of the sqlglot tree (Polars
    SQL has no placeholders); strings stay quoted literals, so a value can never become SQL."""
    bound = bind(relative, values)
    tree = sqlglot.parse_one(query_text(relative), read="duckdb")

    def literal(node: exp.Expression) -> exp.Expression:
        if isinstance(node, exp.Placeholder) and node.name in bound:
            return exp.convert(bound[node.name])
        return node

    return tree.transform(literal).sql("duckdb")


class PolarsEngine(Engine):
    """Polars' SQLContext over the canonical tables (read from the DuckDB file); runs only the queries that
    POLARS_UNSUPPORTED does not list."""

    name = "polars"

    def __init__(self, con: duckdb.DuckDBPyConnection):
        self.con = con
        self.ctx = pl.SQLContext()
        self.inputs = {table.name: con.sql(f"select * from {table.name}").pl().lazy() for table in INPUT_TABLES}
        for name, frame in self.inputs.items():
            self.ctx.register(name, frame)

    def run(self, relative: str, values: dict[str, object]) -> pl.DataFrame:
        """queries/<relative> on Polars SQL, whether or not POLARS_UNSUPPORTED lists it (the verdict tests)."""
        return self.ctx.execute(inline_parameters(relative, values), eager=True)

    def materialise(self, table: str, relative: str, values: dict[str, object]) -> None:
        check_engine(self.name, [relative])
        self.ctx.register(table, self.run(relative, values).lazy())

    def frame(self, sql: str) -> pl.DataFrame:
        return self.ctx.execute(_as_query(sql), eager=True)

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.ctx.register(table, frame.lazy())

    def select_drives(self) -> None:
        batch = self.ctx.execute("select drive_id from run_drives")
        for table in PARTITIONED_BY_DRIVE:
            self.ctx.register(table, self.inputs[table].join(batch, on="drive_id", how="semi"))

    def release_drives(self) -> None:
        for table in PARTITIONED_BY_DRIVE:
            self.ctx.register(table, self.inputs[table])

    def persist(self, tables: tuple[str, ...]) -> None:
        registered = set(self.ctx.tables())
        for table in tables:
            if table in registered:
                _copy_into_duckdb(self.con, table, self.frame(table))
                self.ctx.unregister(table)


# The query files Polars SQL (polars 2.1) cannot run, with the error it gives. Every other query file runs there
# and gives DuckDB's rows: tests/test_polars.py runs each file on both over the same inputs and checks this table
# both ways (docs/engines.md has the table with the reasons).
POLARS_UNSUPPORTED: dict[str, str] = {
    "relations/ego_lanes.sql": "unexpected clause found in 'LAST_VALUE' (IGNORE NULLS)",
    "match/identify.sql": "unsupported function 'md5'",
    "phases/unprotected_left_turn_frames.sql": "unsupported function 'bool_or'",
    "staging/tracks.sql": "unexpected clause found in 'LAST_VALUE' (IGNORE NULLS)",
    "coverage/histogram.sql": 'unable to find column "value_text:b"',  # a LEFT JOIN whose ON has an OR of ranges
}
