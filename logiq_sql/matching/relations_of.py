"""``relations_of(drive_id, ego_id)``: the full ego-actor relation of one ego, computed on demand from the stored
tracks and lanes. ``match`` stores the relation table only with ``--keep``; this table macro gives any ego's
rows as the matcher computes them (the same query files, queries/relations/*.sql, as CTEs), e.g.

    select * from relations_of('USA_US101-22_1_T-1', '675');
    select * from relations_of('junction_s1', 'car_E_left.0', relation_range_m := 100, lane_tolerance_m := 0.5);

``relation_range_m`` (default 200, match --relation-range), ``lane_tolerance_m`` (default 1, the scenarios'
lane_calculation_tolerance_length) and ``min_closing_speed_mps`` (default 0.1, the vehicle scenarios'
min_closing_speed: TTC and MTTC are NULL below it) are the values the matcher would bind; other kinds than vehicles
are related within min(relation_range_m, 50) m, as in match. ``match`` creates the macro in the file it matches.
"""

from __future__ import annotations

import re

import duckdb

from logiq_sql.core.sql import query_text
from logiq_sql.spec.plan import ALL_KINDS_CSV, DEFAULT_MIN_CLOSING_SPEED_MPS, RELATION_STEPS, ego_kinds_csv

STEPS = (("egos", "relations/egos.sql"), *RELATION_STEPS)  # the matcher's relation steps, in its order
# each query parameter -> the macro's expression for it (the ego given by id, in the given drive only)
PARAMETERS = {
    "ego_mode": "'id'",
    "ego_every": "1",
    "ego_actor_ids_csv": "(',' || of_ego || ',')",
    "ego_kinds_csv": "'" + ego_kinds_csv(None) + "'",  # a constant of the code (the kinds under test), not a value
    "min_closing_speed_mps": "min_closing_speed_mps",
    "lane_calculation_tolerance_length_m": "lane_tolerance_m",
    "relation_range_m": "relation_range_m",
    "object_relation_range_m": "least(relation_range_m, 50.0)",
    "relation_kinds_csv": "'" + ALL_KINDS_CSV + "'",  # every kind: the full relation, whatever a run kept
}


def macro_sql() -> str:
    """``create or replace macro relations_of(...) as table ...`` built from the relation query files."""
    def body(relative: str) -> str:
        text = re.sub(r"\$(\w+)\b", lambda m: PARAMETERS[m.group(1)], query_text(relative))
        return "\n".join("    " + line if line else "" for line in text.rstrip().splitlines())

    ctes = ["run_drives as (\n    select of_drive as drive_id\n)"]
    ctes += [f"{table} as (\n{body(relative)}\n)" for table, relative in STEPS]
    return ("create or replace macro relations_of(of_drive, of_ego, relation_range_m := 200.0, "
            f"lane_tolerance_m := 1.0, min_closing_speed_mps := {DEFAULT_MIN_CLOSING_SPEED_MPS}) as table\nwith\n\n" + ",\n\n".join(ctes) + "\n\nselect * from relations")


def install(con: duckdb.DuckDBPyConnection) -> None:
    """Create (or refresh) the relations_of macro in the connection's file."""
    con.execute(macro_sql())
