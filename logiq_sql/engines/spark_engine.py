"""The Spark engine: each step's sqlglot transpile run with ``spark.sql(text, args=...)`` over the canonical tables
as Parquet; the session it uses; ``render --engine spark``."""

from __future__ import annotations

import collections
import functools
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

import duckdb
import polars as pl
import sqlglot
from sqlglot import exp

from logiq_sql.core import schema
from logiq_sql.core.errors import arg
from logiq_sql.core.schema import arrow_type, spark_type
from logiq_sql.core.sql import bind, parsed, query_text, sql_literal, used_values
from logiq_sql.engines.base import (
    INPUT_TABLES,
    PARTITIONED_BY_DRIVE,
    Engine,
    EngineError,
    Reads,
    as_query,
    copy_into_duckdb,
)
from logiq_sql.storage import dataset

SPARK_MASTER_ENV = "SPARK_MASTER"
DEFAULT_SPARK_MASTER = "local[2]"


@functools.cache
def spark_text(relative: str) -> str:
    """queries/<relative> in Spark SQL: sqlglot's DuckDB -> Spark transpile; ``$name`` becomes ``:name``."""
    return sqlglot.transpile(query_text(relative), read="duckdb", write="spark", pretty=True)[0]


@functools.cache
def spark_statements(relative: str) -> tuple[tuple[str | None, str], ...]:
    """queries/<relative> as the Spark statements the engine runs, in order: first each CTE the file reads more than
    once, as ``(view name, its Spark SQL)``, then ``(None, the query's Spark SQL)``, reading those views.

    Spark's optimiser inlines every deterministic CTE at each place it is read (InlineCTE; no setting turns that
    off), so a CTE read three times is planned and computed three times, and the CTEs it reads with it: on
    relations/ego_lanes.sql, whose CTEs read each other in a diamond, even a small scene took longer to optimise than
    to run (benchmarks/README.md, "Figures behind the code's comments"). The engine materialises these CTEs as views first (computed once, as DuckDB
    computes a CTE read more than once), so every statement reads each remaining CTE once. Same SQL, same rows."""
    tree = parsed(relative)
    with_ = tree.args.get("with_")
    if with_ is None or with_.args.get("recursive"):  # a recursive CTE reads itself: left as it is
        return ((None, spark_text(relative)),)
    ctes = {cte.alias: cte.this for cte in with_.expressions}

    def reads(node: exp.Expression) -> list[str]:
        return [t.name for t in node.find_all(exp.Table) if not t.db and t.name in ctes]

    read_count = collections.Counter(reads(tree))
    stem = re.sub(r"\W", "_", relative.removesuffix(".sql"))
    views = {name: f"_cte_{stem}__{name}" for name in ctes if read_count[name] > 1}
    if not views:
        return ((None, spark_text(relative)),)

    def statement(body: exp.Expression) -> str:
        body = body.copy()
        body.set("with_", None)
        needed: list[str] = []  # the CTEs (not made views) that body reads, directly or through each other

        def need(node: exp.Expression) -> None:
            for name in reads(node):
                if name not in views and name not in needed:
                    need(ctes[name])
                    needed.append(name)

        need(body)

        def to_view(node: exp.Expression) -> exp.Expression:
            if isinstance(node, exp.Table) and not node.db and node.name in views:
                return exp.to_table(views[node.name]).as_(node.alias or node.name)  # qualified columns still resolve
            return node

        order = list(ctes)
        if needed:
            body.set("with_", exp.With(expressions=[
                exp.CTE(this=ctes[n].copy(), alias=exp.TableAlias(this=exp.to_identifier(n)))
                for n in sorted(needed, key=order.index)]))
        return body.transform(to_view).sql("spark", pretty=True)

    shared = [(views[name], statement(ctes[name])) for name in ctes if name in views]
    return (*shared, (None, statement(tree)))


# The JVMs of a match run many short jobs, each with code generated for it: the optimising JIT (C2) spends much of
# their CPU compiling code that runs for seconds, so the client JIT alone costs less (benchmarks/README.md, Spark).
# A session logiq-sql starts has these; a user's own session (a notebook's, spark-submit's) takes them from
# session_options() or --conf (docs/engines.md).
JVM_OPTIONS = "-XX:TieredStopAtLevel=1"


def session_options() -> dict[str, str]:
    """The settings of a session for logiq-sql that must be given before it starts (the JVMs' options):
    ``SparkSession.builder.config(map=session_options())``."""
    return {"spark.driver.extraJavaOptions": JVM_OPTIONS, "spark.executor.extraJavaOptions": JVM_OPTIONS}


def spark_session(master: str | None = None):
    """The active Spark session, or a new one on ``master`` (else $SPARK_MASTER, else spark-submit's --master, else
    local[2])."""
    try:
        from pyspark.sql import SparkSession
    except ImportError:
        raise EngineError(f"{arg('engine', 'spark')} needs PySpark and Java 17: pip install "
                          "'logiq-sql[spark]'.") from None
    active = SparkSession.getActiveSession()
    if active is not None:
        if master and active.sparkContext.master != master:
            raise EngineError(f"{arg('spark_master', master)}: this process already has a Spark session on "
                              f"{active.sparkContext.master}; stop it first, or leave the master unset to use it.")
        return active
    # Python steps (SparkEngine.derive) run in the executors' Python, by default `python3` on the PATH: in local
    # mode and on this machine's workers that must be this interpreter, which has the dependencies
    os.environ.setdefault("PYSPARK_PYTHON", sys.executable)
    builder = SparkSession.builder
    master = master or os.environ.get(SPARK_MASTER_ENV)
    if master or "PYSPARK_GATEWAY_PORT" not in os.environ:  # under spark-submit, its --master applies
        builder = builder.master(master or DEFAULT_SPARK_MASTER)
    session = (builder.appName("logiq-sql").config(map=session_options())
               .config("spark.ui.enabled", "false")
               .config("spark.ui.showConsoleProgress", "false")
               .config("spark.sql.shuffle.partitions", "4")
               # a local or client driver JVM starts with this; Spark's smaller default ran out building the broadcast
               # side of a relation join (SPARK_DRIVER_MEMORY to change it; spark-submit's --driver-memory wins)
               .config("spark.driver.memory", os.environ.get("SPARK_DRIVER_MEMORY", "4g"))
               .config("spark.sql.session.timeZone", "UTC")
               # drive ids such as '101' stay strings when read back from partition folder names
               .config("spark.sql.sources.partitionColumnTypeInference.enabled", "false")
               .getOrCreate())
    session.sparkContext.setLogLevel("ERROR")  # Spark's own warnings would drown logiq-sql's progress lines
    return session


def export_parquet(con: duckdb.DuckDBPyConnection, folder: str | Path) -> Path:
    """The canonical input tables of a DuckDB file as a dataset (logiq_sql/storage/dataset.py) in ``folder``, whose
    table folders are replaced: per-drive tables partitioned by drive_id, so a cluster reads only its drives."""
    folder = Path(folder)
    for table in INPUT_TABLES:
        shutil.rmtree(folder / table.name, ignore_errors=True)
    return dataset.write(con, folder, "part")


LONG_MAX = 2**63 - 1


def checkpoint(df):
    """``df`` computed once, its lineage cut (``localCheckpoint``), with a size estimate that stays bounded.

    A checkpoint carries its plan's size estimate, and Spark's size-only estimator multiplies the estimates of a
    join's two sides. Carried from step to step, the estimate's digits grew with every step that joins earlier
    ones: at the SUMO junction, junction_frames' reached 4,040 digits, and a later step's overflowed the driver's
    heap. An estimate past a long (far past every broadcast threshold, so no plan changes) is replaced by Spark's
    default size for a table it knows nothing about, ``spark.sql.defaultSizeInBytes``."""
    from pyspark.sql import DataFrame

    kept = df.localCheckpoint(eager=True)
    try:
        fits = kept._jdf.queryExecution().optimizedPlan().stats().sizeInBytes() <= LONG_MAX
    except ValueError:  # more digits than Python converts: far past a long
        fits = False
    if fits:
        return kept
    jdf = kept.sparkSession._jsparkSession.internalCreateDataFrame(
        kept._jdf.queryExecution().toRdd(), kept._jdf.schema(), False)
    return DataFrame(jdf, kept.sparkSession)


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
        if not dataset.is_dataset(self.folder) or self.own_folder:  # a dataset (ingest --dataset) is read as it is
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

    def keep_frame(self, table: str, df) -> None:
        """Keep the Spark DataFrame ``df`` as the step ``table``: computed once, a temp view of that name."""
        self.describe(f"step {table}")
        self._view(table, checkpoint(df))  # later steps read it many times; plans stay short

    def _view(self, table: str, df) -> None:
        """``df`` as the temp view ``table``, in place of the step of that name before it (whose rows are
        released)."""
        old = self.views.pop(table, None)
        df.createOrReplaceTempView(table)
        self.views[table] = df
        if old is not None:
            old.unpersist()

    def describe(self, what: str | None) -> None:
        """Name the jobs that follow after ``what`` (the Spark UI's and event log's job description)."""
        self.spark.sparkContext.setJobDescription(what)

    def materialise(self, table: str, relative: str, values: dict[str, object], kept: str | None = None) -> None:
        args = bind(relative, values)
        *shared, (_, query) = spark_statements(relative)
        for view, text in shared:  # the CTEs read more than once, computed once (spark_statements)
            self.keep_frame(view, self.spark.sql(text, args=args))
        rows = self.spark.sql(query, args=args)
        self.keep_frame(table, rows.where(kept) if kept else rows)
        self.forget(tuple(view for view, _ in shared))  # the step is computed; it no longer reads them

    def define(self, table: str, relative: str, values: dict[str, object]) -> None:
        """queries/<relative> as the view ``table``, computed as part of the job of the one step that reads it
        (a KPI query, read by its scenario's metrics): no job of its own. A query that needs CTE views of its own
        (spark_statements) is materialised instead."""
        *shared, (_, query) = spark_statements(relative)
        if shared:
            self.materialise(table, relative, values)
            return
        self._view(table, self.spark.sql(query, args=bind(relative, values)))

    def frame(self, sql: str) -> pl.DataFrame:
        text = sqlglot.transpile(as_query(sql), read="duckdb", write="spark")[0]
        return pl.from_arrow(self.spark.sql(text).toArrow())

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.keep_frame(table, self.spark.createDataFrame(frame.to_arrow(compat_level=pl.CompatLevel.oldest())))

    def select_drives(self) -> None:
        # the Parquet is partitioned by drive_id: a semi join with the batch's drives reads only their folders
        batch = self.views["run_drives"]
        for table in PARTITIONED_BY_DRIVE:
            self.inputs[table].join(batch, "drive_id", "left_semi").createOrReplaceTempView(table)

    def release_drives(self) -> None:
        for table in PARTITIONED_BY_DRIVE:
            self.inputs[table].createOrReplaceTempView(table)

    def derive(self, table: str, compute, reads: Reads, schema: dict[str, pl.DataType]) -> None:
        # on the executors, one drive at a time: the rows of every table in ``reads``, only the columns it names,
        # go as one union with prefixed columns to a grouped Arrow UDF that loads them into an in-memory DuckDB and
        # calls ``compute``; only drives with rows in the first table are grouped. Nothing is collected to the
        # driver.
        from pyspark.sql import functions as F
        from pyspark.sql import types as T

        drives = self.spark.table(next(iter(reads))).select("drive_id").distinct()
        parts, columns = [], {}
        for name, wanted in reads.items():
            df = self.spark.table(name).join(drives, "drive_id", "left_semi")
            columns[name] = [(f"{name}__{c}", c) for c in (wanted or df.columns)]
            parts.append(df.select(F.col("drive_id").alias("_drive"), F.lit(name).alias("_table"),
                                   *[F.col(c).alias(alias) for alias, c in columns[name]]))
        packed = functools.reduce(lambda a, b: a.unionByName(b, allowMissingColumns=True), parts)
        struct = T.StructType([T.StructField(c, spark_type(t), True) for c, t in schema.items()])

        def per_drive(rows):  # a plain function: PySpark 4.3's applyInArrow fails on a functools.partial
            return _derive_per_drive(rows, compute, columns, schema)

        self.keep_frame(table, packed.groupBy("_drive").applyInArrow(per_drive, struct))

    def persist(self, tables: tuple[str, ...]) -> None:
        for table in tables:
            if table in self.views:
                copy_into_duckdb(self.con, table, self.frame(table))
        self.forget(tables)

    def forget(self, tables: tuple[str, ...]) -> None:
        """Drop these steps: the next group of the run keeps only what it computes itself."""
        for table in tables:
            if table in self.views:
                self.views.pop(table).unpersist()
                self.spark.catalog.dropTempView(table)

    def close(self) -> None:
        self.describe(None)
        for df in self.views.values():
            df.unpersist()
        for name in (*self.views, *(t.name for t in INPUT_TABLES)):
            self.spark.catalog.dropTempView(name)
        self.views.clear()
        if self.own_folder:
            shutil.rmtree(self.folder, ignore_errors=True)


def _derive_per_drive(packed, compute, columns: dict[str, list[tuple[str, str]]], schema: dict[str, pl.DataType]):
    """SparkEngine.derive on an executor: one drive's packed rows back into their tables, ``compute`` over them."""
    import pyarrow as pa
    import pyarrow.compute as pc

    out = pa.schema([(c, arrow_type(t)) for c, t in schema.items()])
    con = duckdb.connect()
    try:
        for name, cols in columns.items():
            rows = packed.filter(pc.equal(packed["_table"], name)).select([alias for alias, _ in cols])
            con.register(name, rows.rename_columns([c for _, c in cols]))
        return compute(con).select(list(schema)).to_arrow().cast(out)  # Spark wants plain (not large) strings
    finally:
        con.close()


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
        raise EngineError(f"render {arg('engine', name)}: render prints DuckDB (default) or Spark SQL; Polars SQL "
                          "has no parameters, so there is no bound statement to print.")
    text, args = render_spark_steps(steps, values)
    header = [f"-- scenario {s.name} (version {s.version}), params_hash {s.params_hash()}, Spark SQL",
              "-- bind the parameters, never format them in:  spark.sql(text, args={...the values below...})"]
    header += [f"-- :{name} = {sql_literal(value)}" for name, value in args.items()]
    header += ["-- reads the canonical tables (docs/tables.md) and run_drives (drive_id of the drives to match) as "
               "tables or temp views" + ("; encroachments (shapely) as stored by match --keep" if s.junctions else "")]
    header.append("-- for reading and for small runs: Spark 4.3's analyser gives up on a whole scenario as one statement "
                  "(Max iterations (100) for batch Resolution, or a 4 GB driver heap runs out); run it step by step, "
                  "as match --engine spark does (docs/engines.md)")
    return "\n".join(header) + "\n" + text + "\n"
