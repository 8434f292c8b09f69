"""A Spark run's results written by Spark itself as a Parquet dataset: ``match --engine spark --dataset DIR --out OUT``.

Nothing of a batch's results passes through the driver: every output table is a Spark DataFrame built from the
steps the executors computed, appended by the executors as Parquet under OUT, hive-partitioned so that one
drive's results can be replaced alone:

    OUT/<table>/scenario=<name>/drive_id=<id>/part-*.parquet   matches, match_phases, kpis, coverage_samples,
                                                                  drive_scenarios
    OUT/<table>/drive_id=<id>/part-*.parquet                      ego_lanes; relations, passages, encroachments
                                                                  with --keep
    OUT/coverage_buckets/scenario=<name>/                         the buckets of each scenario's coverage items
    OUT/coverage/                                                 histograms over every sample in OUT (Spark,
                                                                  queries/coverage/histogram.sql, at the end)
    OUT/match_runs/run_id=<id>/                                   one row per scenario of the run, at the end

A batch first deletes its drives' folders of the scenarios it reruns (Hadoop's FileSystem API, so OUT may be any
URI the cluster writes: a local or shared folder, HDFS, S3, DBFS), then appends: a rerun replaces, never
duplicates, and a drive whose matches disappeared loses its old rows. A run killed between the two leaves those
drives without rows for the scenario and without a run record: the next run sees them as not matched and does
them again. ``OUT/logiq.duckdb`` gets DuckDB views over every table (``attach_outputs``), beside the views over
the input dataset, so ``query``, ``report``, ``explain`` and notebooks read a Spark run as they read a local one.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core.sql import sql_literal
from logiq_sql.core.timing import stage
from logiq_sql.matching.runner import coverage_buckets, kept_rows
from logiq_sql.spec.contract import sample_columns
from logiq_sql.spec.plan import (
    IDENTIFY_QUERY,
    MATCH_PHASES_QUERY,
    MATCH_ROWS_STEP,
    SAMPLES_QUERY,
    phase_steps,
    run_record,
)
from logiq_sql.spec.scenario import Scenario
from logiq_sql.storage import tables
from logiq_sql.storage.store import PERSISTED, STORED_ALWAYS

# the partition columns of each table under OUT (the folders' names; hive partitions)
PARTITIONS = {**dict.fromkeys(("matches", "match_phases", "kpis", "coverage_samples", "drive_scenarios"),
                              ("scenario", "drive_id")),
              "coverage_buckets": ("scenario",), "match_runs": ("run_id",), "coverage": (),
              **dict.fromkeys(PERSISTED, ("drive_id",))}
OUTPUT_TABLES = {t.name: t for t in tables.OUTPUT_TABLES}


class SparkResults:
    """The results of one run, written under ``out`` by the Spark engine ``engine`` (engines/spark_engine.py)."""

    def __init__(self, engine, out: str | Path, run_id: str, ego: str, range_m: float, keep: bool):
        self.engine, self.spark = engine, engine.spark
        self.out = str(out).rstrip("/")
        self.run_id, self.ego, self.range_m, self.keep = run_id, ego, range_m, keep
        self.started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        self.totals: dict[str, tuple[Scenario, int, int]] = {}  # scenario -> (it, drives, matches) of this run
        jvm = self.spark._jvm
        self._path, self._escape = jvm.org.apache.hadoop.fs.Path, \
            jvm.org.apache.spark.sql.catalyst.catalog.ExternalCatalogUtils.escapePathName
        self._conf = self.spark._jsc.hadoopConfiguration()

    @staticmethod
    def _typed(df, table: str, *extra: str):
        """The columns of the output table ``table`` in its order and types (a bound integer comes back from Spark
        as an int, say), then ``extra``."""
        from pyspark.sql import functions as F

        from logiq_sql.core.schema import spark_type

        t = OUTPUT_TABLES[table]
        return df.select(*[F.col(c.name).cast(spark_type(c.dtype)).alias(c.name) for c in t.columns], *extra)

    # -- the file system, through Hadoop (any URI the cluster can write)
    def _delete(self, relative: str) -> None:
        path = self._path(f"{self.out}/{relative}")
        path.getFileSystem(self._conf).delete(path, True)

    def _folder(self, key: str, value: str) -> str:
        return f"{key}={self._escape(value)}"  # as Spark names the partition folder

    def _clear(self, table: str, drives: list[str], scenario: str | None) -> None:
        """Delete ``drives``' folders of ``table`` (those of ``scenario`` where the table is split by scenario)."""
        head = f"{table}/{self._folder('scenario', scenario)}/" if "scenario" in PARTITIONS[table] else f"{table}/"
        for drive in drives:
            self._delete(head + self._folder("drive_id", drive))

    def _replace(self, table: str, df, drives: list[str], scenario: str | None = None) -> None:
        """``_clear``, then append ``df`` partitioned as PARTITIONS says."""
        self._clear(table, drives, scenario)
        self.engine.describe(f"write {table}")
        df.write.mode("append").partitionBy(*PARTITIONS[table]).parquet(f"{self.out}/{table}")

    # -- one batch
    def write_batch(self, scenarios: list[Scenario], values: dict[str, dict[str, object]],
                    drives: list[str]) -> dict[str, int]:
        """Run ``scenarios`` on the batch whose relations the engine holds, write their outputs, and say how many
        matches each found."""
        for table in PERSISTED:
            if table in self.engine.views and (self.keep or table in STORED_ALWAYS):
                with stage("match: storing results"):
                    self._replace(table, self.spark.table(table), drives)
            elif not self.keep and table not in STORED_ALWAYS:  # rows an earlier run kept would be stale
                self._clear(table, drives, None)
        return {s.name: self._scenario(s, values[s.name], drives) for s in scenarios}

    def _scenario(self, s: Scenario, values: dict[str, object], drives: list[str]) -> int:
        from pyspark.sql import functions as F

        engine, spark = self.engine, self.spark
        with stage(f"scenario {s.name}"):
            for table, rel in phase_steps(s):
                engine.materialise(table, rel, values, kept=kept_rows(s, table))
            engine.materialise("scenario_matches", IDENTIFY_QUERY, values)
            engine.materialise("scenario_match_phases", MATCH_PHASES_QUERY, values)
        matches = spark.table("scenario_matches")
        with stage("kpis"):
            metrics = matches.select("match_id")
            engine.materialise(*MATCH_ROWS_STEP, values)
            for i, rel in enumerate(s.kpi_queries):
                engine.define(f"_kpi_{i}", rel, values)  # computed with the metrics, below
                metrics = metrics.join(spark.table(f"_kpi_{i}"), "match_id", "left")
            if s.sample_queries:
                # each coverage item keeps the value at the event its `sample` names (match/samples.sql): one row
                # per (match, sample), so the first non-NULL value is the value
                engine.materialise("match_samples", SAMPLES_QUERY, values)
                provider = sample_columns(s)
                for j, rel in enumerate(s.sample_queries):
                    engine.materialise(f"_sample_{j}", rel, values)
                    sampled = spark.table(f"_sample_{j}")
                    for item in (c for c in s.coverage if provider.get(c.column) == rel):
                        at = (sampled.where(F.col("sample") == item.sample).groupBy("match_id")
                              .agg(F.first(item.column, ignorenulls=True).alias(item.column)))
                        metrics = metrics.join(at, "match_id", "left")
            engine.keep_frame("_metrics", metrics)
        metrics = spark.table("_metrics")
        drive_of = matches.select("match_id", "drive_id")
        name = F.lit(s.name)
        with stage("match: storing results"):
            self._replace("matches", self._typed(matches.withColumn("run_id", F.lit(self.run_id)), "matches"),
                          drives, s.name)
            phases = spark.table("scenario_match_phases").join(drive_of, "match_id")
            self._replace("match_phases", self._typed(phases, "match_phases", "drive_id"), drives, s.name)
            kpis = metrics.select("match_id", name.alias("scenario"),
                                  *[F.col(c).cast(sql_type if sql_type != "varchar" else "string").alias(c)
                                    for c, (_unit, sql_type, _doc) in s.metric_columns().items()])
            self._replace("kpis", kpis.join(drive_of, "match_id"), drives, s.name)
            samples = None
            for item in s.coverage:
                col = F.col(item.column)
                one = metrics.select(
                    name.alias("scenario"), "match_id", F.lit(item.name).alias("item"), F.lit(item.unit).alias("unit"),
                    (F.lit(None).cast("double") if item.values else col.cast("double")).alias("value_num"),
                    (col.cast("string") if item.values else F.lit(None).cast("string")).alias("value_text"))
                samples = one if samples is None else samples.unionByName(one)
            if samples is not None:
                self._replace("coverage_samples", self._typed(samples.join(drive_of, "match_id"), "coverage_samples",
                                                               "drive_id"), drives, s.name)
            else:
                self._clear("coverage_samples", drives, s.name)
            self._replace("drive_scenarios", self._typed(self._drive_status(s, matches), "drive_scenarios"), drives,
                          s.name)
            self._delete(f"coverage_buckets/{self._folder('scenario', s.name)}")
            buckets = coverage_buckets(s)
            if buckets.height:
                self.spark.createDataFrame(buckets.to_arrow(compat_level=pl.CompatLevel.oldest())) \
                    .coalesce(1).write.mode("append").partitionBy("scenario").parquet(f"{self.out}/coverage_buckets")
            found = matches.count()  # one number to the driver, for the run record
        _, before_drives, before_matches = self.totals.get(s.name, (s, 0, 0))
        self.totals[s.name] = (s, before_drives + len(drives), before_matches + found)
        return found

    def _drive_status(self, s: Scenario, matches):
        """Per drive of the batch: matched, no_match, no_ego or rejected, with its egos and matches."""
        from pyspark.sql import functions as F

        spark = self.spark
        status = spark.table("drive_inputs").select("drive_id", "status")
        egos = spark.table("egos").groupBy("drive_id").agg(F.count("*").alias("egos"))
        per = matches.groupBy("drive_id").agg(F.count("*").alias("matches"))
        frame = (spark.table("run_drives").select("drive_id").join(status, "drive_id", "left")
                 .join(egos, "drive_id", "left").join(per, "drive_id", "left")
                 .withColumn("egos", F.coalesce("egos", F.lit(0)).cast("bigint"))
                 .withColumn("matches", F.coalesce("matches", F.lit(0)).cast("bigint")))
        return frame.select(
            "drive_id", F.lit(s.name).alias("scenario"), F.lit(s.params_hash()).alias("params_hash"), "egos", "matches",
            F.when(F.col("status") == "rejected", "rejected").when(F.col("egos") == 0, "no_ego")
            .when(F.col("matches") > 0, "matched").otherwise("no_match").alias("status"),
            F.lit(self.run_id).alias("run_id"))

    # -- the end of the run
    def finish(self, con: duckdb.DuckDBPyConnection) -> None:
        """The run record, the coverage histograms over every sample in OUT, and the DuckDB views over OUT."""
        if self.totals:
            rows = [run_record(s, run_id=self.run_id, started_at=self.started, ego_mode=self.ego, drives=drives,
                               matches=found, relation_range_m=self.range_m)
                    for s, drives, found in self.totals.values()]
            record = pl.DataFrame(rows, schema=tables.MATCH_RUNS.polars_schema)
            self.spark.createDataFrame(record.to_arrow(compat_level=pl.CompatLevel.oldest())).coalesce(1) \
                .write.mode("append").partitionBy("run_id").parquet(f"{self.out}/match_runs")
        with stage("coverage"):
            self._coverage()
        attach_outputs(con, self.out, [s for s, _, _ in self.totals.values()])

    def _coverage(self) -> None:
        """The histograms over every coverage sample under OUT (queries/coverage/histogram.sql on Spark)."""
        from pyspark.sql import types as T

        from logiq_sql.core.schema import spark_type
        from logiq_sql.engines.spark_engine import spark_text

        spark = self.spark
        for t in (tables.COVERAGE_SAMPLES, tables.COVERAGE_BUCKETS):
            struct = T.StructType([T.StructField(c.name, spark_type(c.dtype), True) for c in t.columns])
            written = self._path(f"{self.out}/{t.name}")
            df = (spark.read.schema(struct).parquet(f"{self.out}/{t.name}").select(*t.column_names)
                  if written.getFileSystem(self._conf).exists(written) else spark.createDataFrame([], struct))
            df.createOrReplaceTempView(t.name)
        histogram = spark.sql(spark_text("coverage/histogram.sql"))
        histogram.coalesce(1).write.mode("overwrite").parquet(f"{self.out}/coverage")


def attach_outputs(con: duckdb.DuckDBPyConnection, out: str | Path, scenarios: list[Scenario]) -> None:
    """Views in ``con`` over the tables under ``out`` (replacing the file's empty tables), with the columns a
    local run's tables have; ``kpis`` has every KPI column found, those of ``scenarios`` first, in their order."""
    out = Path(out)
    columns_of = {t.name: list(t.column_names) for t in tables.OUTPUT_TABLES}
    for name, keys in PARTITIONS.items():
        files = out / name
        if not files.is_dir() or not any(files.rglob("*.parquet")):
            continue
        source = (f"read_parquet({sql_literal(str(files.resolve()) + '/**/*.parquet')}, hive_partitioning = true, "
                  "union_by_name = true" + "".join(
                      ", hive_types = {" + ", ".join(f"'{k}': varchar" for k in keys) + "}" if keys else "") + ")")
        have = [r[0] for r in con.execute(f"describe select * from {source}").fetchall()]
        if name == "kpis":  # a scenario without matches wrote no file: its columns are NULL, typed as declared
            declared = {c: f"cast(null as {sql_type}) as {c}" if c not in have else c
                        for s in scenarios for c, (_unit, sql_type, _doc) in s.metric_columns().items()}
            rest = sorted(set(have) - set(declared) - {"match_id", "scenario", "drive_id"})
            columns = ["match_id", "scenario", *declared.values(), *rest]
        else:  # a kept table: its drive_id first, as in the file of a local run
            columns = columns_of.get(name) or ["drive_id", *(c for c in have if c != "drive_id")]
        kind = dict(con.execute("select table_name, table_type from information_schema.tables "
                                "where table_schema = 'main' and table_name = $t", {"t": name}).fetchall())
        if kind.get(name) == "BASE TABLE":
            con.execute(f"drop table main.{name}")
        con.execute(f"create or replace view main.{name} as select {', '.join(columns)} from {source}")
        con.execute(f"comment on view main.{name} is {sql_literal('A view over the Parquet a Spark run wrote in ' + str(files))}")
    con.execute(tables.DRIVES_VIEW)
