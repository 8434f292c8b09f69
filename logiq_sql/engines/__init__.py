"""The engines that run the query files, by name: DuckDB, the reference (``duckdb_engine.py``), Spark
(``spark_engine.py``) and Polars SQL (``polars_engine.py``), each behind the interface of ``base.Engine``. Decisions,
the per-query Polars verdicts and how to run on a Spark cluster: docs/engines.md."""

from __future__ import annotations

from collections.abc import Callable

import duckdb

from logiq_sql.core.errors import arg
from logiq_sql.engines.base import Engine, EngineError
from logiq_sql.engines.duckdb_engine import DuckEngine
from logiq_sql.engines.polars_engine import PolarsEngine, check_runs
from logiq_sql.engines.spark_engine import SparkEngine

# name -> how to open it on a DuckDB file's connection (con, spark_master, spark_tables, a StepCache or None);
# only the DuckDB engine uses the step cache
ENGINES: dict[str, Callable[..., Engine]] = {
    "duckdb": lambda con, master, tables, cache: DuckEngine(con, cache),
    "spark": lambda con, master, tables, cache: SparkEngine(con, master, tables),
    "polars": lambda con, master, tables, cache: PolarsEngine(con),
}
# what each engine must check before a run starts, beyond the engine being known
PREFLIGHT: dict[str, Callable[[str], None]] = {"polars": check_runs}


def check_engine(name: str, relatives: list[str]) -> None:
    """Raise before anything runs if a query of the run cannot run on engine ``name``."""
    if name not in ENGINES:
        raise EngineError(f"{arg('engine', name)}: choose one of {', '.join(ENGINES)}.")
    for rel in relatives:
        PREFLIGHT.get(name, lambda _: None)(rel)


def open_engine(name: str, con: duckdb.DuckDBPyConnection, spark_master: str | None = None,
                spark_tables: str | None = None, cache=None) -> Engine:
    """The engine ``name`` on ``con``; ``cache`` (a StepCache) is used by the DuckDB engine only."""
    check_engine(name, [])
    return ENGINES[name](con, spark_master, spark_tables, cache)


def as_engine(con_or_engine: duckdb.DuckDBPyConnection | Engine) -> Engine:
    """Callers that hold a DuckDB connection (explain, tests) keep passing it; the matcher passes an engine."""
    if isinstance(con_or_engine, duckdb.DuckDBPyConnection):
        return DuckEngine(con_or_engine)
    return con_or_engine
