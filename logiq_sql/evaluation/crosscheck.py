"""Cross-check logiq_sql's per-frame TTC against SUMO's SSM device, and its speed/acceleration KPIs against FCD.

SUMO's SSM device logs, per encounter of two vehicles, the minimum TTC it saw (``<minTTC time value type>``).
For car following (type 2: the reporting vehicle follows the foe in its lane) SSM's TTC is the bumper-to-bumper
gap along the lane divided by the closing speed, the same definition as ``relations.ttc_s``. This module reads
those records and looks up logiq_sql's ``ttc_s`` of the same (follower as ego, leader as actor) pair at the same
frame. It reads SUMO's records for evaluation only; they never feed matching.
"""

from __future__ import annotations

import gzip
import xml.etree.ElementTree as ET
from pathlib import Path

import duckdb
import polars as pl

from logiq_sql.core.errors import InputError
from logiq_sql.core.sql import registered

FOLLOWING_FOLLOWER = "2"  # SSM encounter type: the reporting vehicle (ego) follows the foe
SSM_SCHEMA = {"ego_id": pl.String, "actor_id": pl.String, "t_s": pl.Float64, "ssm_ttc_s": pl.Float64}


def read_ssm_following_ttc(path: str | Path) -> pl.DataFrame:
    """One row per SSM encounter whose minimum TTC was measured while the ego followed the foe (type 2).

    Every encounter is written twice by SUMO (once from each vehicle, types 2 and 3 mirrored); keeping type 2
    keeps each once, with the follower as ego. SSM files hold extremes only, so they are small.
    """
    path = Path(path)
    try:
        with (gzip.open(path) if path.name.endswith(".gz") else open(path, "rb")) as f:
            root = ET.parse(f).getroot()
    except (OSError, EOFError, ET.ParseError) as exc:
        raise InputError(f"{path}: not a readable SSM output file ({exc}).") from None
    rows = [
        {"ego_id": c.get("ego"), "actor_id": c.get("foe"), "t_s": float(m.get("time")),
         "ssm_ttc_s": float(m.get("value"))}
        for c in root.iter("conflict")
        for m in c.iter("minTTC")
        if m.get("type") == FOLLOWING_FOLLOWER and m.get("value") not in (None, "NA")
    ]
    return pl.DataFrame(rows, schema=SSM_SCHEMA)


def ttc_against_ssm(con: duckdb.DuckDBPyConnection, drive_id: str, ssm: pl.DataFrame) -> pl.DataFrame:
    """SSM's minimum TTC of each following pair next to ``relations.ttc_s`` at the same frame.

    ``relations`` must hold the SSM followers as egos (e.g. ``match --ego <their ids>``). ``ttc_s`` is NULL
    where logiq_sql finds the pair not closing or not in line, and the row is then a disagreement.
    """
    with registered(con, "_ssm", ssm.with_columns(pl.lit(drive_id).alias("drive_id"))):
        return con.sql("""
            select s.drive_id, s.ego_id, s.actor_id, s.t_s, s.ssm_ttc_s, r.ttc_s, r.same_lane,
                   abs(r.ttc_s - s.ssm_ttc_s) as abs_error_s
            from _ssm as s
            inner join drive_inputs as d on s.drive_id = d.drive_id
            left join relations as r
                on r.drive_id = s.drive_id and r.ego_id = s.ego_id and r.actor_id = s.actor_id
                and r.frame = cast(round(s.t_s / d.dt_s) as bigint)
            order by s.ego_id, s.actor_id, s.t_s
        """).pl()
