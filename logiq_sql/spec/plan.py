"""What a match run does, before any data is read: the scenarios with their overrides, the SUT choice, the values
every step binds, and the steps in order (also rendered as one readable statement).

    egos -> lane_line, lane_neighbours, actor_lanes, ego_lanes -> relations     shared by the scenarios of a group
    [junction steps, encroachments]                                              scenarios with junctions = true
    [scenario_frames] -> phase_1 .. phase_n -> phase_frames, scenario_phases -> phase_runs -> chain
        -> scenario_match -> scenario_matches, scenario_match_phases                   per scenario
"""

from __future__ import annotations

import hashlib
import json

from logiq_sql.core import units
from logiq_sql.core.errors import ScenarioError, arg, did_you_mean
from logiq_sql.core.schema import EGO_KINDS, OBJECT_KINDS
from logiq_sql.core.sql import per_phase, query_text
from logiq_sql.spec.contract import PHASE_VALUES, check_scenario
from logiq_sql.spec.scenario import FRAMES_TABLE, Scenario, ScenarioPath, list_scenarios, load_scenario

DEFAULT_RELATION_RANGE = "200m"  # a 5 s headway (the lane-following maximum) at 140 km/h
OBJECT_RELATION_RANGE_M = 50.0  # non-vehicle actors are related to the ego only this close
DEFAULT_LANE_TOLERANCE_M = 1.0  # the spec's default lane_calculation_tolerance_length
DEFAULT_MIN_CLOSING_SPEED_MPS = 0.1  # logiq_base_vehicle_scenario's min_closing_speed, for scenarios without it
ALL_KINDS_CSV = "," + ",".join(OBJECT_KINDS) + ","  # $relation_kinds_csv when every kind is related (relations_of)
# the kinds that can be under test (--ego auto/all/every:N); --ego-kinds narrows them
EGO_KIND_ALIASES = {"car": "vehicle"}
RELATION_STEPS = (
    ("lane_line", "relations/lane_line.sql"),
    ("lane_neighbours", "relations/lane_neighbours.sql"),
    ("actor_lanes", "relations/actor_lanes.sql"),
    ("ego_lanes", "relations/ego_lanes.sql"),
    ("ego_road", "relations/ego_road.sql"),
    ("relations", "relations/relations.sql"),
)
# junction geometry, for the scenarios that declare `junctions = true`; encroachments (shapely) come after them
JUNCTION_STEPS = (
    ("actor_paths", "junctions/actor_paths.sql"),
    ("passages", "junctions/passages.sql"),
    ("junction_frames", "junctions/junction_frames.sql"),
    ("crossing_pairs", "junctions/crossing_pairs.sql"),
)
# the phases as rows: each a select written for phase 1, run for every phase of a scenario (sql.per_phase), its
# rows keyed by the actors' integer keys
PHASE_FRAMES_QUERY = "match/phase_frames.sql"
SCENARIO_PHASES_QUERY = "match/scenario_phases.sql"
# the generic steps every scenario's phases go through (the phase contract, docs/scenarios.md)
MATCH_STEPS = (
    ("phase_runs", "match/phase_runs.sql"),
    ("chain", "match/chain.sql"),
    ("scenario_match", "match/sequential.sql"),
)
IDENTIFY_QUERY = "match/identify.sql"
MATCH_PHASES_QUERY = "match/match_phases.sql"
SAMPLES_QUERY = "match/samples.sql"
# the rows of tracks and relations inside the matches' intervals, which the KPI and sample queries read
MATCH_ROWS_STEP = ("match_rows", "kpis/match_rows.sql")


def parse_ego(ego: str, kinds: str | None = None) -> dict[str, object]:
    """``auto | recorded | all | every:N | <actor id>[,<actor id>...]`` and the kinds that can be under test
    (``vehicle,truck``; default EGO_KINDS) -> the egos.sql parameters."""
    ego_kinds = ego_kinds_csv(kinds)
    if ego in ("auto", "recorded", "all"):
        return {"ego_mode": ego, "ego_every": 1, "ego_actor_ids_csv": "", "ego_kinds_csv": ego_kinds}
    if ego.startswith("every:"):
        try:
            n = int(ego.split(":", 1)[1])
            if n < 1:
                raise ValueError
        except ValueError:
            raise ScenarioError(f"{arg('ego', ego)}: N in every:N must be a whole number >= 1.") from None
        return {"ego_mode": "every", "ego_every": n, "ego_actor_ids_csv": "", "ego_kinds_csv": ego_kinds}
    return {"ego_mode": "id", "ego_every": 1, "ego_kinds_csv": ego_kinds,
            "ego_actor_ids_csv": "," + ",".join(i.strip() for i in ego.split(",")) + ","}


def relation_range_m(text: str) -> float:
    """``relation_range`` (``--relation-range``) in metres."""
    return units.parse(text, "length", arg("relation_range", text))


def ego_kinds_csv(kinds: str | None) -> str:
    """``--ego-kinds car,truck`` -> ``,vehicle,truck,`` (checked against the evaluation_object_kinds)."""
    if kinds is None:
        return "," + ",".join(EGO_KINDS) + ","
    chosen = [EGO_KIND_ALIASES.get(k.strip(), k.strip()) for k in kinds.split(",") if k.strip()]
    if not chosen:
        raise ScenarioError(f"{arg('ego_kinds', kinds)}: name at least one kind, e.g. vehicle,truck.")
    for kind in chosen:
        if kind not in OBJECT_KINDS:
            raise ScenarioError(f"{arg('ego_kinds', kinds)}: '{kind}' is not an evaluation_object_kind."
                                f"{did_you_mean(kind, OBJECT_KINDS)}\n\nHint: e.g. vehicle (car), truck, bus.")
    return "," + ",".join(chosen) + ","


def ego_key(ego: str, kinds: str | None) -> str:
    """How a run records its SUT choice (match_runs.ego_mode): ``--ego`` and, when narrowed, the kinds."""
    return ego if kinds is None else f"{ego};kinds={ego_kinds_csv(kinds).strip(',')}"


def resolve_scenarios(names: list[str] | None, overrides: dict[str, str],
                      scenario_path: ScenarioPath = None) -> list[Scenario]:
    """Load the scenarios (built-in and the user's folder), check each against its SQL (logiq_sql.spec.contract),
    and apply each override to every scenario that declares that parameter."""
    scenarios = ([load_scenario(n, scenario_path) for n in names] if names
                 else list_scenarios(scenario_path))
    abstract = [s.name for s in scenarios if s.abstract]
    if abstract:
        raise ScenarioError(f"scenario '{abstract[0]}' is a base scenario and cannot be matched on its own.")
    problems = [p for s in scenarios for p in check_scenario(s, scenario_queries(s))]
    if problems:
        raise ScenarioError("\n".join(problems) + "\n\nHint: `logiq-sql lint` lists every problem; the contract is "
                                                  "in docs/scenarios.md.")
    known = {p for s in scenarios for p in s.params}
    for name, text in overrides.items():
        if name not in known:
            raise ScenarioError(
                f"{arg('overrides', text, name)}: no scenario of this run has a parameter '{name}'."
                f"{did_you_mean(name, sorted(known))}\n\nHint: `logiq-sql scenarios` lists every parameter."
            )
    return [s.with_overrides({k: v for k, v in overrides.items() if k in s.params}) for s in scenarios]


def _value_or(s: Scenario, name: str, default: float) -> float:
    p = s.params.get(name)
    return float(p.value) if p is not None and p.value is not None else default


def relation_settings(s: Scenario) -> tuple[float, float]:
    """What the shared relation steps depend on (scenarios that agree on it share one relations table): the lane
    tolerance and the least closing speed of TTC/MTTC."""
    return (_value_or(s, "lane_calculation_tolerance_length", DEFAULT_LANE_TOLERANCE_M),
            _value_or(s, "min_closing_speed", DEFAULT_MIN_CLOSING_SPEED_MPS))


def relation_kinds_csv(group: list[Scenario]) -> str:
    """The actor kinds the relation steps of ``group`` (scenarios that share one relations table) compute, as
    ``$relation_kinds_csv``: the union of the scenarios' ``relation_kinds``, every kind when one of them leaves it
    unset. ``relations`` then holds only pairs some scenario of the group can use; ``relations_of`` gives every
    kind."""
    if any(s.relation_kinds is None for s in group):
        return ALL_KINDS_CSV
    kinds = {k for s in group for k in s.relation_kinds or ()}
    return "," + ",".join(k for k in OBJECT_KINDS if k in kinds) + ","


def phase_values(s: Scenario) -> dict[str, object]:
    """Per phase i of ``s``: ``phase_<i>_name``, ``phase_<i>_min_duration_s`` (0 when none) and
    ``phase_<i>_max_duration_s`` (NULL when none): the values the phase's duration parameters have
    (match/scenario_phases.sql)."""
    out: dict[str, object] = {"phase_count": len(s.phases)}
    for i, phase in enumerate(s.phases, 1):
        lo = s.params[phase.min_duration].value if phase.min_duration else None
        hi = s.params[phase.max_duration].value if phase.max_duration else None
        out.update(zip((f"phase_{i}_{what}" for what in PHASE_VALUES), (phase.name, 0.0 if lo is None else lo, hi)))
    return out


def run_values(s: Scenario, ego: dict[str, object], relation_range_m: float) -> dict[str, object]:
    """Every value a step of scenario ``s`` may bind."""
    tolerance_m, closing_mps = relation_settings(s)
    return {
        "max_gap_s": 0.0, **s.bindings(), **phase_values(s), **ego, "relation_range_m": relation_range_m,
        "object_relation_range_m": min(relation_range_m, OBJECT_RELATION_RANGE_M),
        "relation_kinds_csv": relation_kinds_csv([s]),
        "lane_calculation_tolerance_length_m": tolerance_m, "min_closing_speed_mps": closing_mps,
        "scenario": s.name, "scenario_version": s.version, "params_hash": s.params_hash(),
    }


def phase_steps(s: Scenario) -> list[tuple[str, str]]:
    """The steps from the relations to the scenario's matches (table, query): the optional frames step, each
    phase's query, the phases as rows (the frames at which each holds, and their names and duration limits), then
    the generic runs, chain and match."""
    steps = [(FRAMES_TABLE, s.frames_query)] if s.frames_query else []
    steps += [(f"phase_{i}", p.query) for i, p in enumerate(s.phases, 1)]
    steps += [("phase_frames", per_phase(PHASE_FRAMES_QUERY, len(s.phases))),
              ("scenario_phases", per_phase(SCENARIO_PHASES_QUERY, len(s.phases)))]
    return [*steps, *MATCH_STEPS]


def scenario_steps(s: Scenario) -> list[tuple[str, str]]:
    """Every SQL step of a scenario, in order. Junction scenarios also read ``encroachments``, which shapely
    computes between crossing_pairs and the phases (logiq_sql/matching/encroachment.py); rendered SQL reads the stored
    table."""
    return [("egos", "relations/egos.sql"), *RELATION_STEPS, *(JUNCTION_STEPS if s.junctions else ()),
            *phase_steps(s)]


def result_steps(s: Scenario) -> list[tuple[str, str]]:
    """The steps after the phases, in the runner's order (table, query): the matches and their phases, the rows
    inside their intervals, each KPI query, then the sample events and each sample query over them."""
    steps = [("scenario_matches", IDENTIFY_QUERY), ("scenario_match_phases", MATCH_PHASES_QUERY), MATCH_ROWS_STEP]
    steps += [("_kpi", rel) for rel in s.kpi_queries]
    if s.sample_queries:
        steps += [("match_samples", SAMPLES_QUERY), *[("_sample", rel) for rel in s.sample_queries]]
    return steps


def scenario_queries(s: Scenario) -> list[str]:
    """Every query file a run of ``s`` executes, in order."""
    return [rel for _, rel in [*scenario_steps(s), *result_steps(s)]]


def queries_hash(s: Scenario) -> str:
    """Short digest of the text of every query a run of ``s`` executes: a drive is up to date for ``s`` only while
    this and the params_hash are those of its latest run, so an edited query reruns its drives without a version
    bump (the step cache then recomputes the steps whose text changed and those after them)."""
    digest = hashlib.sha256()
    for rel in scenario_queries(s):
        digest.update(rel.encode() + b"\0" + query_text(rel).encode() + b"\0")
    return digest.hexdigest()[:16]


def run_record(s: Scenario, *, run_id: str, started_at: str, ego_mode: str, drives: int, matches: int,
               relation_range_m: float) -> dict[str, object]:
    """The match_runs row of a run of ``s`` (docs/tables.md): the values it bound, so every match can be rerun."""
    return {"run_id": run_id, "started_at": started_at, "scenario": s.name, "scenario_version": s.version,
            "params_hash": s.params_hash(), "queries_hash": queries_hash(s),
            "params_json": json.dumps(s.bindings(), sort_keys=True),
            "overrides": json.dumps(s.overrides, sort_keys=True), "ego_mode": ego_mode, "drives": drives,
            "matches": matches, "relation_range_m": relation_range_m}
