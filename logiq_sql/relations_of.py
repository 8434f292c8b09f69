"""``relations_of(drive_id, ego_id)``: the full ego-actor relation of one ego, computed on demand from the stored
tracks and lanes. ``match`` stores the relation table only with ``--keep``; this table macro gives any ego's
rows as the matcher computes them (the same query files, queries/relations/*.sql, as CTEs), e.g.

    select * from relations_of('USA_US101-22_1_T-1', '675');
    select * from relations_of('junction_s1', 'car_E_left.0', relation_range_m := 100, lane_tolerance_m := 0.5);

``relation_range_m`` (default 200, match --relation-range) and ``lane_tolerance_m`` (default 1, the scenarios'
lane_calculation_tolerance_length) are the values the matcher would bind; other kinds than vehicles are related
within min(relation_range_m, 50) m, as in match. ``match`` creates the macro in the file it matches.
"""

from __future__ import annotations

import re

import duckdb

from logiq_sql.sql import query_text

STEPS = ("egos", "lane_neighbours", "lane_line", "actor_lanes", "ego_lanes", "relations")
# each query parameter -> the macro's expression for it (the ego given by id, in the given drive only)
PARAMETERS = {
    "ego_mode": "'id'",
    "ego_every": "1",
    "ego_actor_ids_csv": "(',' || of_ego || ',')",
    "lane_calculation_tolerance_length_m": "lane_tolerance_m",
    "relation_range_m": "relation_range_m",
    "object_relation_range_m": "least(relation_range_m, 50.0)",
}


def macro_sql() -> str:
    """``create or replace macro relations_of(...) as table ...`` built from the relation query files."""
    def body(step: str) -> str:
        text = re.sub(r"\$(\w+)\b", lambda m: PARAMETERS[m.group(1)], query_text(f"relations/{step}.sql"))
        return "\n".join("    " + line if line else "" for line in text.rstrip().splitlines())

    ctes = ["run_drives as (\n    select of_drive as drive_id\n)"]
    ctes += [f"{step} as (\n{body(step)}\n)" for step in STEPS]
    return ("create or replace macro relations_of(of_drive, of_ego, relation_range_m := 200.0, "
            "lane_tolerance_m := 1.0) as table\nwith\n\n" + ",\n\n".join(ctes) + "\n\nselect * from relations")


def install(con: duckdb.DuckDBPyConnection) -> None:
    """Create (or refresh) the relations_of macro in the connection's file."""
    con.execute(macro_sql())
