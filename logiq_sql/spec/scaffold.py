"""``logiq-sql new-scenario NAME --extends BASE``: a scenario of one's own to start from, a TOML file and its SQL.

The scaffold is a working scenario, not a blank form: a vehicle_actor in the Ego's lane, behind it, at most
``max_time_headway`` away, for at least ``min_close_follow_duration``. It passes ``lint`` and matches on the bundled
drives as written, so each edit can be checked against a scenario that worked (docs/scenarios.md).
"""

from __future__ import annotations

import re
from pathlib import Path

from logiq_sql.core.errors import ScenarioError, arg
from logiq_sql.spec.scenario import load_scenario, scenario_files

NAME = re.compile(r"^[a-z][a-z0-9_]*$")

TOML = '''# {name}: written by `logiq-sql new-scenario {name} --extends {base}`; the file's keys and the phase contract
# are in docs/scenarios.md. Check each edit with `logiq-sql lint {name} --scenario-path {folder}`.
name = "{name}"
extends = ["{base}"]
description = "A vehicle_actor follows the Ego in its lane, at most max_time_headway behind it (edit me)."
version = 1

[params.max_time_headway]
type = "time"
default = "2s"
description = "Longest time headway of the vehicle_actor behind the Ego"

[params.min_close_follow_duration]
type = "time"
default = "1s"
description = "Shortest time the vehicle_actor follows that close"

[[phases]]
name = "{name}"
query = "{name}.sql"
min_duration = "min_close_follow_duration"
conditions = [
    {{ name = "actor_kind_ok", value = "actor_kind", test = "in kinds" }},
    {{ name = "behind_in_lane", value = "dx_m", test = "< 0, in the Ego's lane" }},
    {{ name = "close", value = "time_headway_s", test = "<= max_time_headway" }},
]
'''

SQL = '''-- phase: {name} (written by `logiq-sql new-scenario`; the phase contract: docs/scenarios.md)
-- One row per (drive, ego, actor, frame) of the relation table (its columns: docs/semantics.md): each condition
-- as a column named as in the TOML file, the values the conditions read, and `holds`: exactly the AND of the
-- condition columns (`logiq-sql lint` checks it against the TOML file, so `explain` can name each one).
with

conditions as (
    select
        r.drive_id,
        r.ego_id,
        r.actor_id,
        r.drive_key,
        r.ego_key,
        r.actor_key,
        r.frame,
        r.t_s,
        0 as segment,  -- nothing cuts the phase; e.g. the Ego's lane run would end it at a lane change
        coalesce(instr($kinds_csv, ',' || r.actor_kind || ',') > 0, false) as actor_kind_ok,
        coalesce(r.same_lane and r.dx_m < 0, false) as behind_in_lane,
        coalesce(r.time_headway_s <= $max_time_headway_s, false) as close,
        r.actor_kind,
        r.dx_m,
        r.time_headway_s
    from relations as r
)

select
    *,
    actor_kind_ok and behind_in_lane and close as holds
from conditions
'''


def new_scenario(name: str, base: str, folder: str | Path) -> list[Path]:
    """Write ``folder/name.toml`` and ``folder/name.sql``, a scenario extending ``base``; never overwrites."""
    folder = Path(folder)
    if not NAME.match(name):
        raise ScenarioError(f"{arg('name', name)}: write the name in lower case letters, digits and _, starting "
                            "with a letter (it names the files, the phase and the matches' scenario column).")
    taken = scenario_files(folder if folder.is_dir() else None)
    if name in taken:
        raise ScenarioError(f"{arg('name', name)}: a scenario of that name exists already ({taken[name]}); "
                            "choose another name.")
    parent = load_scenario(base, folder if folder.is_dir() else None)
    if "kinds" not in parent.params:
        raise ScenarioError(f"{arg('extends', base)}: the scaffold's phase reads a vehicle_actor's relation to the "
                            "Ego, so its base needs the kinds parameter: extend logiq_base_vehicle_scenario or a "
                            "scenario that extends it (e.g. logiq_base_lane_following_scenario).")
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{name}.toml", folder / f"{name}.sql"]
    for path in paths:
        if path.exists():
            raise ScenarioError(f"{path}: exists already; new-scenario never overwrites a file.")
    for path, text in zip(paths, (TOML, SQL), strict=True):
        path.write_text(text.format(name=name, base=base, folder=folder))
    return paths
