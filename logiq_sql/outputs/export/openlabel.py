"""ASAM OpenLABEL 1.0 export: one JSON file per drive with its scenario matches.

Mapping (docs/formats.md):
    metadata: schema_version 1.0.0, name = drive_id, annotator logiq-sql, comment = source format and path.
    frame_intervals: the drive's frames (tracks.frame, first to last).
    tags: one per scenario matched in the drive, type = the scenario name, tag_data num ``matches``.
    objects: the recorded ego and every ego and actor of a match; type = kind, name = actor_id, frame_intervals =
        the runs of consecutive frames the actor has tracks in; object_data: text actor_id, boolean is_ego,
        num length_m and width_m (the first row's).
    actions: one per match (type = the scenario, frame interval = start_frame..end_frame, action_data: text
        match_id, ego_id, actor_id; num start_s, end_s; then every KPI of the match, a num per numeric KPI, a text
        per enum/string KPI, a boolean per boolean one, NULL KPIs left out) and one per phase (type = the phase name, frame interval = the
        phase's, action_data: text match_id and scenario, num phase_index).
    relations: per match, ``is_ego_of`` (ego object -> match action) and ``is_actor_of`` (actor object -> match
        action), over the match's frames.
UIDs are numbers in the order the elements are listed (objects by actor_id, actions by start frame).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import polars as pl

from logiq_sql.core.sql import registered
from logiq_sql.outputs.export import OPENLABEL_SCHEMA, open_db

_MATCH_COLUMNS = {"match_id", "scenario"}


def _interval(start: int, end: int) -> dict:
    return {"frame_start": int(start), "frame_end": int(end)}


def _data(values: dict) -> dict:
    """OpenLABEL element data of named values: a text per string, a boolean per bool, a num per number; NULL and
    non-finite values left out."""
    out: dict[str, list] = {}
    for name, v in values.items():
        if isinstance(v, bool):
            out.setdefault("boolean", []).append({"name": name, "val": v})
        elif isinstance(v, int | float):
            if math.isfinite(v):
                out.setdefault("num", []).append({"name": name, "val": float(v)})
        elif v is not None:
            out.setdefault("text", []).append({"name": name, "val": str(v)})
    return out


# runs of consecutive frames per actor of _export_actors (gaps and islands), its kind and first box
ACTOR_INTERVALS_SQL = """
with rows as (
    select t.drive_id, t.actor_id, kind, is_ego, frame, length_m, width_m,
           frame - row_number() over (partition by t.drive_id, t.actor_id order by frame) as island
    from tracks t join _export_actors a on t.drive_id = a.drive_id and t.actor_id = a.actor_id),
islands as (
    select drive_id, actor_id, min(frame) as s, max(frame) as e, arg_min(kind, frame) as kind,
           bool_or(is_ego) as is_ego, arg_min(length_m, frame) as length_m,
           arg_min(width_m, frame) as width_m
    from rows group by drive_id, actor_id, island)
select drive_id, actor_id, arg_min(kind, s) as kind, bool_or(is_ego) as is_ego,
       arg_min(length_m, s) as length_m, arg_min(width_m, s) as width_m,
       list(struct_pack(frame_start := s, frame_end := e) order by s) as intervals
from islands group by drive_id, actor_id order by drive_id, actor_id
"""


def export_openlabel(db_path: str | Path, out: str | Path, drives: list[str] | None = None) -> list[Path]:
    """Write ``{drive_id}.json`` into ``out`` for every ingested drive (or those named); returns the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with open_db(db_path) as con:
        have = {r[0] for r in con.execute("select table_name from duckdb_tables()").fetchall()}
        inputs = con.sql("select drive_id, source_format, source_path, ego_actor_id from drive_inputs "
                             "where status = 'ingested' order by drive_id").pl()
        if drives:
            inputs = inputs.filter(pl.col("drive_id").is_in(drives))
        with registered(con, "_export_drives", inputs.select("drive_id")):
            matches = con.sql("select * from matches where drive_id in (select drive_id from _export_drives) "
                              "order by drive_id, start_frame, match_id").pl()
            with registered(con, "_export_matches", matches.select("match_id")):
                phases = con.sql("select * from match_phases where match_id in (select match_id from "
                                 "_export_matches) order by match_id, phase_index").pl()
                kpis = (con.sql("select * from kpis where match_id in (select match_id from _export_matches)").pl()
                        if "kpis" in have else pl.DataFrame({"match_id": []}, schema={"match_id": pl.String}))
            # every actor to describe: the recorded ego and the egos and actors of matches
            with registered(con, "_export_actors", pl.concat([
                    inputs.select("drive_id", actor_id="ego_actor_id").drop_nulls(),
                    matches.select("drive_id", actor_id="ego_id"), matches.select("drive_id", "actor_id")]).unique()):
                actors = con.sql(ACTOR_INTERVALS_SQL).pl()
            frames = dict(con.execute("select drive_id, [min(frame), max(frame)] from tracks "
                                      "where drive_id in (select drive_id from _export_drives) group by 1").fetchall())
    kpi_by_match = {r["match_id"]: r for r in kpis.to_dicts()}
    written = []
    for drive in inputs.to_dicts():
        drive_id = drive["drive_id"]
        label = _drive_label(drive, frames.get(drive_id), actors.filter(pl.col("drive_id") == drive_id),
                             matches.filter(pl.col("drive_id") == drive_id), phases, kpi_by_match)
        path = out / f"{_file_name(drive_id)}.json"
        path.write_text(json.dumps(label, indent=1) + "\n")
        written.append(path)
    return written


def _file_name(drive_id: str) -> str:
    """The drive_id, or where it has other characters than letters, digits, - _ and ., those replaced by _ and
    the first 8 hex digits of its MD5 appended (two ids never share a file)."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in drive_id)
    return safe if safe == drive_id else f"{safe}-{hashlib.md5(drive_id.encode()).hexdigest()[:8]}"


def _drive_label(drive: dict, frame_range, actors: pl.DataFrame, matches: pl.DataFrame, phases: pl.DataFrame,
                 kpi_by_match: dict) -> dict:
    label: dict = {"metadata": {
        "schema_version": "1.0.0", "name": drive["drive_id"], "annotator": "logiq-sql",
        "comment": f"scenario matches found by logiq-sql in {drive['source_format']} drive {drive['source_path']}"}}
    if frame_range:
        label["frame_intervals"] = [_interval(*frame_range)]
    objects, uid_of = {}, {}
    for i, a in enumerate(actors.to_dicts()):
        uid_of[a["actor_id"]] = str(i)
        objects[str(i)] = {
            "name": a["actor_id"], "type": a["kind"],
            "frame_intervals": [_interval(iv["frame_start"], iv["frame_end"]) for iv in a["intervals"]],
            "object_data": _data({"actor_id": a["actor_id"], "length_m": a["length_m"], "width_m": a["width_m"],
                                  "is_ego": bool(a["is_ego"])}),
        }
    if objects:
        label["objects"] = objects
    actions, relations = {}, {}
    for m in matches.to_dicts():
        uid = str(len(actions))
        kpi = {k: v for k, v in kpi_by_match.get(m["match_id"], {}).items() if k not in _MATCH_COLUMNS}
        data = _data({"match_id": m["match_id"], "ego_id": m["ego_id"], "actor_id": m["actor_id"],
                      "start_s": m["start_s"], "end_s": m["end_s"], **kpi})
        actions[uid] = {"name": f"{m['scenario']} {m['match_id']}", "type": m["scenario"],
                        "frame_intervals": [_interval(m["start_frame"], m["end_frame"])], "action_data": data}
        for predicate, who in (("is_ego_of", m["ego_id"]), ("is_actor_of", m["actor_id"])):
            if who in uid_of:
                relations[str(len(relations))] = {
                    "name": f"{who} {predicate} {m['match_id']}", "type": predicate,
                    "frame_intervals": [_interval(m["start_frame"], m["end_frame"])],
                    "rdf_subjects": [{"type": "object", "uid": uid_of[who]}],
                    "rdf_objects": [{"type": "action", "uid": uid}]}
        for p in phases.filter(pl.col("match_id") == m["match_id"]).to_dicts():
            actions[str(len(actions))] = {
                "name": f"{m['scenario']} {p['phase']} {m['match_id']}", "type": p["phase"],
                "frame_intervals": [_interval(p["start_frame"], p["end_frame"])],
                "action_data": _data({"match_id": m["match_id"], "scenario": m["scenario"],
                                      "phase_index": p["phase_index"]})}
    if actions:
        label["actions"] = actions
    if relations:
        label["relations"] = relations
    counts = matches.group_by("scenario").len().sort("scenario").to_dicts()
    if counts:
        label["tags"] = {str(i): {"type": c["scenario"], "tag_data": {"num": [{"name": "matches", "val": c["len"]}]}}
                         for i, c in enumerate(counts)}
    return {"openlabel": label}


def validate_openlabel(path: str | Path) -> None:
    """Raise when the file is not valid against the ASAM OpenLABEL 1.0.0 JSON schema (needs the [formats]
    extra)."""
    import jsonschema

    schema = json.loads(OPENLABEL_SCHEMA.read_text())
    jsonschema.Draft7Validator(schema).validate(json.loads(Path(path).read_text()))
