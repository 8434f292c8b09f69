"""Running a scenario's steps on an engine: the shared relations, then per scenario its phases, matches, KPIs
and coverage samples, as Polars frames for ``logiq_sql.storage.store``."""

from __future__ import annotations

import re
from collections import Counter

import duckdb
import polars as pl

from logiq_sql.core.sql import step_key, tables_read
from logiq_sql.core.timing import stage
from logiq_sql.engines import as_engine
from logiq_sql.engines.base import Engine
from logiq_sql.matching.encroachment import ENCROACHMENT_READS, ENCROACHMENTS_SCHEMA, encroachments
from logiq_sql.spec.contract import output_columns, sample_columns
from logiq_sql.spec.plan import (
    ALL_KINDS_CSV,
    IDENTIFY_QUERY,
    JUNCTION_STEPS,
    MATCH_PHASES_QUERY,
    MATCH_ROWS_STEP,
    RELATION_STEPS,
    SAMPLES_QUERY,
    phase_steps,
    relation_kinds_csv,
)
from logiq_sql.spec.scenario import FRAMES_TABLE, Scenario
from logiq_sql.storage.store import ScenarioOutput
from logiq_sql.storage.tables import COVERAGE_BUCKETS, COVERAGE_SAMPLES

# what run_scenario writes besides the phase steps' tables: a query reading one of them depends on the scenario
SCENARIO_TABLES = ("scenario_matches", "scenario_match_phases", MATCH_ROWS_STEP[0], "_kpi", "match_samples", "_sample")


def prepare_relations(con: duckdb.DuckDBPyConnection | Engine, group: list[Scenario],
                      values: dict[str, object], every_kind: bool = False) -> None:
    """The steps every scenario of ``group`` (one set of relation settings) shares: egos, relations and, when one
    of them needs it, the junction geometry and the encroachment areas. ``relations`` holds the actors of the
    kinds some scenario of ``group`` can use (``plan.relation_kinds_csv``), or of every kind with ``every_kind``
    (``explain``, which shows the pairs a scenario cannot match too)."""
    engine = as_engine(con)
    engine.owners = tuple(s.name for s in group)
    values = {**values, "relation_kinds_csv": ALL_KINDS_CSV if every_kind else relation_kinds_csv(group)}
    engine.shared = True
    try:
        with stage("relations"):
            engine.materialise("egos", "relations/egos.sql", values)
            for table, rel in RELATION_STEPS:
                engine.materialise(table, rel, values)
        if any(s.junctions for s in group):
            with stage("junctions"):
                for table, rel in JUNCTION_STEPS:
                    engine.materialise(table, rel, values)
                engine.derive("encroachments", encroachments, ENCROACHMENT_READS, ENCROACHMENTS_SCHEMA)
    finally:
        engine.shared = False


def shared_phase_steps(group: list[Scenario], values: dict[str, dict[str, object]]) -> frozenset[tuple[str, tuple]]:
    """The phase steps that more than one scenario of ``group`` runs with the same values (by scenario name in
    ``values``) and that read none of the tables a scenario writes, only the group's shared ones: the same rows
    each time (phases/ego_on_same_lane.sql in sut_cut_out and in cut_in_ahead_of_ego), for ``Engine.share``."""
    written = {table for s in group for table, _ in phase_steps(s)} | set(SCENARIO_TABLES)
    runs = Counter(step_key(p.query, values[s.name]) for s in group for p in s.phases
                   if not tables_read(p.query) & written)
    return frozenset(key for key, n in runs.items() if n > 1)


def coverage_buckets(s: Scenario) -> pl.DataFrame:
    """Every bucket of every coverage item of ``s`` (half-open numeric buckets, or one per enum value)."""
    rows = []
    for item in s.coverage:
        if item.values:
            rows += [dict(scenario=s.name, item=item.name, bucket_index=i, bucket=v, lo=None, hi=None, value_text=v)
                     for i, v in enumerate(item.values)]
            continue
        n = round((item.hi - item.lo) / item.every)
        for i in range(n):
            lo = item.lo + i * item.every
            hi = min(item.lo + (i + 1) * item.every, item.hi)
            rows.append(dict(scenario=s.name, item=item.name, bucket_index=i, bucket=f"[{lo:g}, {hi:g})",
                             lo=lo, hi=hi, value_text=None))
    return pl.DataFrame(rows, schema=COVERAGE_BUCKETS.polars_schema)


def coverage_samples(s: Scenario, metrics: pl.DataFrame) -> pl.DataFrame:
    """One coverage sample per match and item, from the metrics frame (one row per match)."""
    frames = []
    for item in s.coverage:
        col = pl.col(item.column)
        frames.append(metrics.select(
            pl.lit(s.name).alias("scenario"), pl.col("match_id"), pl.lit(item.name).alias("item"),
            pl.lit(item.unit).alias("unit"),
            (pl.lit(None, pl.Float64) if item.values else col.cast(pl.Float64)).alias("value_num"),
            (col.cast(pl.String) if item.values else pl.lit(None, pl.String)).alias("value_text"),
        ))
    return pl.concat(frames) if frames else pl.DataFrame(schema=COVERAGE_SAMPLES.polars_schema)


def kept_rows(s: Scenario, table: str) -> str | None:
    """The boolean column whose true rows a match keeps of the step ``table`` (None: every row). ``holds`` for a
    phase step: the runs and the KPIs read no other rows. ``may_hold`` for a frames step that has it: the rows that
    can hold, or that the phases read, for some value of the parameters. explain computes every row, to say which
    condition failed."""
    if re.fullmatch(r"phase_\d+", table) is not None:
        return "holds"
    if table == FRAMES_TABLE and "may_hold" in (output_columns(s.frames_query) or ()):
        return "may_hold"
    return None


def run_scenario(engine: Engine, s: Scenario, values: dict[str, object]) -> ScenarioOutput:
    """The scenario's phases, matches, KPIs and coverage samples on the batch's relations."""
    engine.owners = (s.name,)
    with stage(f"scenario {s.name}"):
        for table, rel in phase_steps(s):
            engine.materialise(table, rel, values, kept=kept_rows(s, table))
        engine.materialise("scenario_matches", IDENTIFY_QUERY, values)
        engine.materialise("scenario_match_phases", MATCH_PHASES_QUERY, values)
        matches = engine.frame("scenario_matches")
        phases = engine.frame("scenario_match_phases")
    metrics = matches.select("match_id")
    with stage("kpis"):
        engine.materialise(*MATCH_ROWS_STEP, values)
        for rel in s.kpi_queries:
            engine.materialise("_kpi", rel, values)
            metrics = metrics.join(engine.frame("_kpi"), on="match_id", how="left")
        if s.sample_queries:
            # each coverage item keeps the value at the event its `sample` names (match/samples.sql)
            engine.materialise("match_samples", SAMPLES_QUERY, values)
            provider = sample_columns(s)
            for rel in s.sample_queries:
                engine.materialise("_sample", rel, values)
                sampled = engine.frame("_sample")
                for item in (c for c in s.coverage if provider.get(c.column) == rel):
                    at = (sampled.filter(pl.col("sample") == item.sample)
                          .group_by("match_id").agg(pl.col(item.column).drop_nulls().first()))
                    metrics = metrics.join(at, on="match_id", how="left")
    kpis = metrics.select(pl.col("match_id"), pl.lit(s.name).alias("scenario"),
                          *[pl.col(c) for c in s.metric_columns()])
    egos = engine.frame("select drive_id, count(*) as egos from egos group by drive_id")
    return ScenarioOutput(s, matches, phases, kpis, coverage_samples(s, metrics), coverage_buckets(s), egos)
