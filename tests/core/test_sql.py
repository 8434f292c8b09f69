"""The SQL tree: portable, every parameter declared, and the rendered SQL reruns to the same matches."""

from __future__ import annotations

import duckdb
import polars as pl
import sqlglot

from logiq_sql.cli.lint import lint_sql, lint_tree
from logiq_sql.core.paths import data_dir
from logiq_sql.core.sql import bind, header, placeholders, query_text
from logiq_sql.matching.match import match, render
from logiq_sql.spec.plan import parse_ego, run_values, scenario_queries
from logiq_sql.spec.scenario import list_scenarios
from tests.helpers import Y1, actor, make_db, times


def test_every_query_is_portable_and_its_header_says_what_it_reads_and_binds():
    assert lint_tree() == []


def test_a_header_that_drifted_from_its_query_is_a_lint_problem(tmp_path):
    root = tmp_path / "queries"
    (root / "match").mkdir(parents=True)
    query = ("-- reads: runs, egos (remark, with a comma)\n-- params: $phase_1_name, $phase_2_name, $phase_3_name\n"
             "with c as (select * from runs) select $phase_1_name, $phase_2_name, $phase_4_name, * from c join t using (k)")
    (root / "match/q.sql").write_text(query)
    assert lint_tree(root) == [
        "queries/match/q.sql: '-- params:' lists phase_3_name, which the query does not use; drop it from the header",
        "queries/match/q.sql: the query uses phase_4_name, which '-- params:' does not list; add it to the header",
        "queries/match/q.sql: '-- reads:' lists egos, which the query does not use; drop it from the header",
        "queries/match/q.sql: the query uses t, which '-- reads:' does not list; add it to the header"]
    (root / "match/q.sql").write_text("select 1 as x")
    assert lint_tree(root) == [
        "queries/match/q.sql: no '-- reads:' header line (the tables it reads; 'none' when there is none)",
        "queries/match/q.sql: no '-- params:' header line (the $parameters it binds; 'none' when there is none)"]


def test_a_query_header_is_read_once_for_its_fields_and_its_column_docs():
    text = ("-- grain: one row per (drive_id, frame) for every actor\n--        within range\n-- reads: tracks\n--\n"
            "--   dx_m, dy_m   actor centre\n--                in the ego frame\n--   holds  true\n--\n"
            "-- params: none\nselect 1\n-- grain: not the header")
    found = header(text)
    assert found.fields == {"grain": "one row per (drive_id, frame) for every actor within range", "reads": "tracks",
                            "params": "none"}
    assert found.columns == {"dx_m": "actor centre in the ego frame", "dy_m": "actor centre in the ego frame",
                             "holds": "true"}
    # a grain written over two lines is whole in the kept relations table's comment
    assert header(query_text("relations/relations.sql")).fields["grain"].endswith("within relation_range of an ego")


def test_lint_catches_what_transpiling_lets_through():
    problems = lint_sql("select a.x / b.y from a asof join b on a.t >= b.t", "q.sql")
    assert problems == [
        "q.sql: ASOF JOIN runs only on DuckDB; use a range join with row_number() = 1",
        "q.sql: division 'a.x / b.y' is not guarded; Spark raises on division by zero where DuckDB returns inf: "
        "divide by nullif(x, 0) or inside a CASE that excludes 0",
    ]
    assert lint_sql("select sum(x) over (order by t range between 1 preceding and current row) from a", "r.sql") == [
        "r.sql: RANGE window frames do not run on Polars; use ROWS over frames"]


def test_lint_catches_what_sqlglot_transpiles_silently_wrong():
    where = "q.sql"
    found = {
        "select list(x order by t) from a": "becomes collect_list on Spark and loses its order",
        "select to_timestamp(t_s) from a": "drop fractional seconds or become their inverse",
        "select epoch_ms(t_ms) from a": "drop fractional seconds or become their inverse",
        "select epoch(ts) from a": "epoch() drops fractional seconds",
        "select quantile_cont(x, 0.5) from a": "wrong argument count",
        "select l[1:2] from a": "list slices",
        "select len(s) from a": "len() becomes a string function",
        "select columns('x.*') from a": "COLUMNS() is DuckDB-only",
    }
    for text, reason in found.items():
        problems = lint_sql(text, where)
        assert len(problems) == 1 and reason in problems[0], (text, problems)


def test_every_query_transpiles_to_spark_with_named_markers():
    for path in sorted(data_dir("queries").rglob("*.sql")):
        (spark,) = sqlglot.transpile(path.read_text(), read="duckdb", write="spark")
        for name in placeholders(str(path.relative_to(data_dir("queries")))):
            assert f":{name}" in spark, (path, name)


def test_every_scenario_parameter_reaches_its_sql():
    """Each query's $parameters are bound by the scenario (or the run); no parameter is declared and unused."""
    for s in list_scenarios():
        values = run_values(s, parse_ego("auto"), 150.0)
        used = set()
        for rel in scenario_queries(s):
            used |= set(bind(rel, values))
        # a phase's duration limits reach the match query as phase_<i>_min/max_duration_s
        used |= {s.params[name].sql_name for i, phase in enumerate(s.phases, 1)
                 for name, alias in ((phase.min_duration, f"phase_{i}_min_duration_s"),
                                     (phase.max_duration, f"phase_{i}_max_duration_s")) if name and alias in used}
        declared = {p.sql_name for p in s.params.values()}
        assert declared <= used, (s.name, declared - used)


def test_rendered_sql_reruns_to_the_same_matches(tmp_path):
    t = times(6.0)
    db = make_db(tmp_path, [actor("ego", t, 100 + 10 * t, Y1, is_ego=True), actor("f", t, 80 + 10 * t, Y1),
                            actor("c", t, 104 + 8 * t, 5.5, kind="cyclist", length=1.8, width=0.6)])
    for scenario, overrides in (("follower_vehicle", {"min_scenario_duration": "2s"}),
                                ("cyclist_close_to_moving_sut", {"max_distance_from_cyclist": "4m"})):
        expected = match(db, scenarios=[scenario], overrides=overrides).matches.select(
            "drive_id", "ego_id", "actor_id", "start_frame", "end_frame").sort("actor_id", "start_frame")
        assert expected.height > 0
        with duckdb.connect(str(db)) as con:  # as an analyst would: the printed text, run as it is
            result = con.execute(render(scenario, overrides=overrides))
            rows = pl.DataFrame(result.fetchall(), schema=[d[0] for d in result.description], orient="row")
        got = rows.select("drive_id", "ego_id", "actor_id", "start_frame", "end_frame").sort("actor_id", "start_frame")
        assert got.equals(expected), scenario
