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

import collections
import functools
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import duckdb
import polars as pl
import sqlglot
from sqlglot import exp

from logiq_sql import dataset, schema
from logiq_sql.errors import LogiqError, arg
from logiq_sql.paths import query_path
from logiq_sql.sql import bind, cte_names, materialise, query_text, sql_literal, step_key, tables_read, used_values

ENGINES = ("duckdb", "spark", "polars")
SPARK_MASTER_ENV = "SPARK_MASTER"
DEFAULT_SPARK_MASTER = "local[2]"
# the canonical tables a match reads; Spark's Parquet copies of the per-drive ones are partitioned by drive_id
INPUT_TABLES = (*schema.ALL_INPUT_TABLES, schema.STORED_TRACK_LANES)
PARTITIONED_BY_DRIVE = ("tracks", "track_lanes", "traffic_light_states")
# what a step may read besides other steps: the canonical tables (a drive's rows and its map's, versioned by
# ingest_versions) and the batch's drive ids
DRIVE_INPUT_NAMES = frozenset({*(t.name for t in INPUT_TABLES), "run_drives"})


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
    owners: tuple[str, ...] = ()  # the scenarios the next steps are run for (the step cache's entries)

    def materialise(self, table: str, relative: str, values: dict[str, object], holding: bool = False) -> None:
        """queries/<relative> with ``values`` bound, kept as ``table``; ``holding``: only its rows whose ``holds``
        is true (a phase step in a match, where nothing reads the others: ``runner.run_scenario``)."""
        raise NotImplementedError

    def frame(self, sql: str) -> pl.DataFrame:
        raise NotImplementedError

    def register(self, table: str, frame: pl.DataFrame) -> None:
        raise NotImplementedError

    def share(self, steps: frozenset[tuple[str, tuple]]) -> None:
        """``steps`` (``sql.step_key``s) are phase steps that several scenarios of the group about to run compute
        with the same values from the group's shared tables: an engine may compute each once (DuckEngine does),
        until ``release_drives``."""

    def select_drives(self) -> None:
        """From now on the per-drive input tables hold only the drives of ``run_drives`` (the batch)."""

    def release_drives(self) -> None:
        """Undo ``select_drives``."""

    def derive(self, table: str, compute, reads: tuple[str, ...], schema: dict[str, pl.DataType]) -> None:
        """Make ``table`` from ``compute(con)``, a Python step (shapely) that queries the tables ``reads`` (all
        keyed by drive_id) through a DuckDB connection and returns a Polars frame of ``schema``. Here it runs once
        over the whole batch; Spark runs it per drive on the executors."""
        self.register(table, compute(self))

    def persist(self, tables: tuple[str, ...]) -> None:
        """Copy the step tables among ``tables`` that this group made into DuckDB temp tables, then forget them."""

    def close(self) -> None:
        """Release what the engine holds (Spark views, exported Parquet)."""


class DuckEngine(Engine):
    """The reference: every step is a temp table of the DuckDB file's connection."""

    name = "duckdb"

    def __init__(self, con: duckdb.DuckDBPyConnection, cache=None):
        self.con = con
        self.cache = cache  # a logiq_sql.step_cache.StepCache, or None: every step runs
        self._shared: frozenset[tuple[str, tuple]] = frozenset()
        self._kept: dict[tuple[str, tuple], str] = {}  # a shared step -> the temp table holding its rows
        self._views: set[str] = set()  # step tables that are views of a kept table
        self._keys: dict[str, str | None] = {}  # the batch's step tables -> their cache keys (None: not cacheable)

    def _cache_key(self, text: str, bound: dict[str, object], reads: frozenset[str]) -> str | None:
        """The step's cache key, or None when the cache is off or the step reads a table of unknown content."""
        if self.cache is None or not self.cache.usable:
            return None
        inputs: dict[str, str] = {}
        for name in reads:
            if name in self._keys:
                if self._keys[name] is None:
                    return None
                inputs[name] = self._keys[name]
            elif name not in DRIVE_INPUT_NAMES:
                return None
        return self.cache.key(text, bound, inputs)

    def _cached(self, table: str, step: str, key: str | None, compute) -> None:
        """``table`` from the cache under ``key`` if it holds the batch's rows, else ``compute()``d (and kept)."""
        if key is not None and self.cache.load(table, key):
            self._keys[table] = key
            self.cache.record(self.owners, step, table, key, computed=False)
            return
        started = time.process_time()
        compute()
        self._keys[table] = key
        if key is not None:
            self.cache.record(self.owners, step, table, key, computed=True,
                              compute_s=time.process_time() - started)

    def materialise(self, table: str, relative: str, values: dict[str, object], holding: bool = False) -> None:
        if table in self._views:  # a table cannot replace a view
            self.con.execute(f"drop view {table}")
            self._views.discard(table)
        text = query_text(relative) + ("\n-- only the rows where holds" if holding else "")  # other rows, other key
        key = self._cache_key(text, bind(relative, values), tables_read(relative) - cte_names(relative))
        self._cached(table, f"{table} {relative}", key, lambda: self._compute(table, relative, values, holding))

    def derive(self, table: str, compute, reads: tuple[str, ...], schema: dict[str, pl.DataType]) -> None:
        key = None if self.cache is None else self._cache_key(self.cache.source_text(compute), {}, frozenset(reads))
        self._cached(table, f"{table} {compute.__module__}", key, lambda: self.register(table, compute(self)))

    def _compute(self, table: str, relative: str, values: dict[str, object], holding: bool) -> None:
        key = step_key(relative, values) if any(relative == rel for rel, _ in self._shared) else None
        if key not in self._shared:
            materialise(self.con, table, relative, values, holding)
            return
        # computed once, read by each scenario through a view: at tier S ego_on_same_lane.sql costs about 2 CPU s,
        # a copy of its 1.1 M rows 0.6
        if key not in self._kept:  # (shared steps are phase steps of a match: each reader asks for the same rows)
            self._kept[key] = f"_shared_step_{len(self._kept) + 1}"
            materialise(self.con, self._kept[key], relative, values, holding)
        self.con.execute(f"drop table if exists temp.main.{table}")
        self.con.execute(f"create temp view {table} as select * from {self._kept[key]}")
        self._views.add(table)

    def share(self, steps: frozenset[tuple[str, tuple]]) -> None:
        self._forget_shared()
        self._shared = steps

    def _forget_shared(self) -> None:
        for view in self._views:
            self.con.execute(f"drop view if exists {view}")
        for kept in self._kept.values():
            self.con.execute(f"drop table if exists {kept}")
        self._shared, self._kept, self._views = frozenset(), {}, set()

    def frame(self, sql: str) -> pl.DataFrame:
        return self.con.sql(_as_query(sql)).pl()

    def register(self, table: str, frame: pl.DataFrame) -> None:
        self.con.register(f"_{table}", frame)
        self.con.execute(f"create or replace temp table {table} as select * from _{table}")
        self.con.unregister(f"_{table}")
        self._keys[table] = None  # rows from elsewhere: steps reading them are not cached

    def select_drives(self) -> None:
        self._keys = {}
        if self.cache is not None:
            self.cache.start_batch()
        # a temp table shadows the stored table of the same name, so every query of the batch reads the batch's
        # rows: a batch then costs what its drives hold, not what the whole file holds (at 10 M rows, queries
        # reading the whole track_lanes per batch made matching grow with batches x file size)
        stored = stored_schema(self.con)
        (others,) = self.con.execute(f"select count(*) from {stored}.drive_inputs where status = 'ingested' and "
                                     "drive_id not in (select drive_id from run_drives)").fetchall()[0]
        if not others:  # the batch is every drive of the file: its tables already hold just the batch's rows
            return
        for table in PARTITIONED_BY_DRIVE:
            self.con.execute(f"create or replace temp table {table} as select * from {stored}.{table} "
                             "where drive_id in (select drive_id from run_drives)")

    def release_drives(self) -> None:
        self._forget_shared()
        self._keys = {}
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


@functools.cache
def spark_statements(relative: str) -> tuple[tuple[str | None, str], ...]:
    """queries/<relative> as the Spark statements the engine runs, in order: first each CTE the file reads more than
    once, as ``(view name, its Spark SQL)``, then ``(None, the query's Spark SQL)``, reading those views.

    Spark's optimiser inlines every deterministic CTE at each place it is read (InlineCTE; no setting turns that
    off), so a CTE read three times is planned and computed three times, and the CTEs it reads with it: on
    relations/ego_lanes.sql, whose CTEs read each other in a diamond, one small nuScenes scene took about 30 s of
    CPU to optimise and 37 s to run. The engine materialises these CTEs as views first (computed once, as DuckDB
    computes a CTE read more than once), so every statement reads each remaining CTE once. Same SQL, same rows."""
    tree = sqlglot.parse_one(query_text(relative), read="duckdb")
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
    session = (builder.appName("logiq-sql")
               .config("spark.ui.enabled", "false")
               .config("spark.ui.showConsoleProgress", "false")
               .config("spark.sql.shuffle.partitions", "4")
               # a local or client driver JVM starts with this; Spark's 1 GB default ran out building the broadcast
               # side of a relation join (SPARK_DRIVER_MEMORY to change it; spark-submit's --driver-memory wins)
               .config("spark.driver.memory", os.environ.get("SPARK_DRIVER_MEMORY", "4g"))
               .config("spark.sql.session.timeZone", "UTC")
               # drive ids such as '101' stay strings when read back from partition folder names
               .config("spark.sql.sources.partitionColumnTypeInference.enabled", "false")
               .getOrCreate())
    session.sparkContext.setLogLevel("ERROR")  # Spark's own warnings would drown logiq-sql's progress lines
    return session


def export_parquet(con: duckdb.DuckDBPyConnection, folder: str | Path) -> Path:
    """The canonical input tables of a DuckDB file as a dataset (logiq_sql/dataset.py) in ``folder``, whose
    table folders are replaced: per-drive tables partitioned by drive_id, so a cluster reads only its drives."""
    folder = Path(folder)
    for table in INPUT_TABLES:
        shutil.rmtree(folder / table.name, ignore_errors=True)
    return dataset.write(con, folder, "part")


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
        old = self.views.pop(table, None)
        df = df.localCheckpoint(eager=True)  # later steps read it many times; plans stay short
        df.createOrReplaceTempView(table)
        self.views[table] = df
        if old is not None:
            old.unpersist()

    def materialise(self, table: str, relative: str, values: dict[str, object], holding: bool = False) -> None:
        args = bind(relative, values)
        *shared, (_, query) = spark_statements(relative)
        for view, text in shared:  # the CTEs read more than once, computed once (spark_statements)
            self.keep_frame(view, self.spark.sql(text, args=args))
        rows = self.spark.sql(query, args=args)
        self.keep_frame(table, rows.where("holds") if holding else rows)
        self.forget(tuple(view for view, _ in shared))  # the step is computed; it no longer reads them

    def frame(self, sql: str) -> pl.DataFrame:
        text = sqlglot.transpile(_as_query(sql), read="duckdb", write="spark")[0]
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

    def derive(self, table: str, compute, reads: tuple[str, ...], schema: dict[str, pl.DataType]) -> None:
        # on the executors, one drive at a time: the rows of every table in ``reads`` go, as one union with
        # prefixed columns, to a grouped Arrow UDF that loads them into an in-memory DuckDB and calls ``compute``;
        # only drives with rows in reads[0] are grouped. Nothing is collected to the driver.
        from pyspark.sql import functions as F
        from pyspark.sql import types as T

        drives = self.spark.table(reads[0]).select("drive_id").distinct()
        parts, columns = [], {}
        for name in reads:
            df = self.spark.table(name).join(drives, "drive_id", "left_semi")
            columns[name] = [(f"{name}__{c}", c) for c in df.columns]
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
                _copy_into_duckdb(self.con, table, self.frame(table))
        self.forget(tables)

    def forget(self, tables: tuple[str, ...]) -> None:
        """Drop these steps: the next group of the run keeps only what it computes itself."""
        for table in tables:
            if table in self.views:
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


def _derive_per_drive(packed, compute, columns: dict[str, list[tuple[str, str]]], schema: dict[str, pl.DataType]):
    """SparkEngine.derive on an executor: one drive's packed rows back into their tables, ``compute`` over them."""
    import pyarrow as pa
    import pyarrow.compute as pc

    arrow_types = {pl.String: pa.string(), pl.Float64: pa.float64(), pl.Int64: pa.int64(), pl.Boolean: pa.bool_()}
    out = pa.schema([(c, arrow_types[t if isinstance(t, type) else type(t)]) for c, t in schema.items()])
    con = duckdb.connect()
    try:
        for name, cols in columns.items():
            rows = packed.filter(pc.equal(packed["_table"], name)).select([alias for alias, _ in cols])
            con.register(name, rows.rename_columns([c for _, c in cols]))
        return compute(con).select(list(schema)).to_arrow().cast(out)  # Spark wants plain (not large) strings
    finally:
        con.close()


def check_engine(name: str, relatives: list[str]) -> None:
    """Raise before anything runs if a query of the run cannot run on engine ``name``."""
    if name not in ENGINES:
        raise EngineError(f"{arg('engine', name)}: choose one of {', '.join(ENGINES)}.")
    for rel in relatives:
        if name == "polars" and (reason := polars_blocker(rel)):
            raise EngineError(f"{arg('engine', 'polars')}: queries/{rel} cannot run on Polars SQL: {reason}. "
                              "Run this scenario on the duckdb or spark engine (docs/engines.md: what runs where).")


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


def open_engine(name: str, con: duckdb.DuckDBPyConnection, spark_master: str | None = None,
                spark_tables: str | None = None, cache=None) -> Engine:
    """The engine ``name`` on ``con``; ``cache`` (a StepCache) is used by the DuckDB engine only."""
    if name == "duckdb":
        return DuckEngine(con, cache)
    if name == "spark":
        return SparkEngine(con, spark_master, spark_tables)
    if name == "polars":
        return PolarsEngine(con)
    raise EngineError(f"{arg('engine', name)}: choose one of {', '.join(ENGINES)}.")


# --------------------------------------------------------------------------------------------------- Polars


OVERRIDES = "overrides"  # queries/overrides/<engine>/<relative>: an engine's own text of a portable query file


def override(engine: str, relative: str) -> str | None:
    """queries/overrides/<engine>/<relative> when that file exists (queries/overrides/README.md), else None."""
    candidate = f"{OVERRIDES}/{engine}/{relative}"
    return candidate if query_path(candidate).is_file() else None


def inline_parameters(relative: str, values: dict[str, object]) -> exp.Expression:
    """queries/<relative> parsed, with every ``$name`` replaced by its value as a literal node of the sqlglot tree
    (Polars SQL has no placeholders); strings stay quoted literals, so a value can never become SQL."""
    bound = bind(relative, values)
    tree = sqlglot.parse_one(query_text(relative), read="duckdb")

    def literal(node: exp.Expression) -> exp.Expression:
        if isinstance(node, exp.Placeholder) and node.name in bound:
            return exp.convert(bound[node.name])
        return node

    return tree.transform(literal)


def digests_after(tree: exp.Expression) -> list[str]:
    """Polars has no md5: each output column ``md5(x) as c`` of the outer select becomes ``x as c`` (in place),
    and the engine hashes those columns afterwards. Returns their names; an md5 elsewhere stays and fails."""
    names = []
    for projection in getattr(tree, "expressions", []):
        if isinstance(projection, exp.Alias) and isinstance(projection.this, exp.MD5):
            projection.set("this", projection.this.this)
            names.append(projection.alias)
    return names


def polars_text(relative: str, values: dict[str, object], portable: bool = False) -> tuple[str, list[str]]:
    """The Polars SQL the engine runs for queries/<relative>: its Polars override, if any (unless ``portable``),
    with the values inlined; and the columns to hash with md5 afterwards (none when ``portable``)."""
    chosen = relative if portable else (override("polars", relative) or relative)
    tree = inline_parameters(chosen, values)
    digests = [] if portable else digests_after(tree)
    return tree.sql("duckdb"), digests


def polars_blocker(relative: str) -> str | None:
    """Why the Polars engine cannot run queries/<relative> (Polars SQL's error on the portable text), or None:
    the file runs as it is, has an override, or needs only the md5 the engine computes afterwards."""
    reason = POLARS_UNSUPPORTED.get(relative)
    if reason is None or override("polars", relative) is not None:
        return None
    if reason == POLARS_MD5:
        tree = sqlglot.parse_one(query_text(relative), read="duckdb")
        digests_after(tree)
        return reason if tree.find(exp.MD5) is not None else None
    return reason


class PolarsEngine(Engine):
    """Polars' SQLContext over the canonical tables (read from the DuckDB file). A query file runs as its Polars
    override where queries/overrides/polars/ has one; the match ids' md5 is DuckDB's, over the key text Polars
    built (Polars has no md5, and the ids must stay those of every other engine); files that polars_blocker
    names do not run."""

    name = "polars"

    def __init__(self, con: duckdb.DuckDBPyConnection):
        self.con = con
        self.ctx = pl.SQLContext()
        self.inputs = {table.name: con.sql(f"select * from {table.name}").pl().lazy() for table in INPUT_TABLES}
        for name, frame in self.inputs.items():
            self.ctx.register(name, frame)

    def run(self, relative: str, values: dict[str, object], portable: bool = False) -> pl.DataFrame:
        """queries/<relative> on Polars SQL as the engine runs it; ``portable``: the portable text as it is, with
        no override and no md5 afterwards (the verdict tests)."""
        text, digests = polars_text(relative, values, portable)
        result = self.ctx.execute(text, eager=True)
        for column in digests:
            result = self._md5(result, column)
        return result

    def _md5(self, frame: pl.DataFrame, column: str) -> pl.DataFrame:
        """``column`` replaced by DuckDB's md5 of it, over its distinct values and joined back (row order kept)."""
        keys = frame.select(pl.col(column).unique())
        self.con.register("_md5_keys", keys)
        try:
            digests = self.con.sql(f'select "{column}", md5("{column}") as _md5 from _md5_keys').pl()
        finally:
            self.con.unregister("_md5_keys")
        return (frame.join(digests, on=column, how="left", nulls_equal=True, maintain_order="left")
                .with_columns(pl.col("_md5").alias(column)).drop("_md5"))

    def materialise(self, table: str, relative: str, values: dict[str, object], holding: bool = False) -> None:
        check_engine(self.name, [relative])
        rows = self.run(relative, values)
        self.ctx.register(table, (rows.filter(pl.col("holds")) if holding else rows).lazy())

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


POLARS_MD5 = "unsupported function 'md5'"
# The query files whose portable text Polars SQL (polars 2.1) cannot run, with the error it gives. Every other
# query file runs there and gives DuckDB's rows: tests/test_polars.py runs each file on both over the same inputs
# and checks this table both ways, and checks that each Polars override (and the md5 afterwards) gives DuckDB's
# rows. polars_blocker says which of these the engine still runs (docs/engines.md has the table).
POLARS_UNSUPPORTED: dict[str, str] = {
    "match/identify.sql": POLARS_MD5,
    # windows over the input order (an empty OVER ()), which DuckDB keeps and the other engines do not: ingest
    # runs on DuckDB only
    "staging/tracks.sql": "LAG requires an ORDER BY in the OVER clause",
}
