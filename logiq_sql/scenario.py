"""Scenarios: declarative TOML files in ``scenarios/`` that name their SQL and declare parameters with units.

A scenario file may ``extends`` base scenarios. What it inherits:
- ``params``: every parameter of every base; the child may redeclare one to change its default.
- ``kpi_queries``, ``kpis`` and ``coverage``: appended, bases first, each name once.
- ``phases`` and ``match``: a concrete scenario declares its own.

Parameter values are parsed once, here, into canonical units. SQL reads them as ``$<name><suffix>``
(``max_distance_from_cyclist`` of type length is ``$max_distance_from_cyclist_m``); ``kinds`` is
``$kinds_csv`` (``",vehicle,truck,"``). Nothing is ever formatted into SQL text.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from logiq_sql import units
from logiq_sql.errors import ScenarioError, did_you_mean
from logiq_sql.paths import data_dir
from logiq_sql.schema import OBJECT_KINDS, VEHICLE_KINDS

PARAM_TYPES = (*units.DIMENSIONS, "kinds")
_PARAM_KEYS = {"type", "default", "description"}
_TOP_KEYS = {
    "name", "description", "spec", "version", "abstract", "extends", "actors", "params", "phases",
    "match", "kpi_queries", "kpis", "coverage", "junctions",
}


@dataclass(frozen=True)
class Param:
    name: str
    type: str
    text: str | None  # as written (default or override), None when unset
    value: float | tuple[str, ...] | None  # canonical unit, or the kinds tuple
    description: str
    declared_in: str

    @property
    def sql_name(self) -> str:
        if self.type == "kinds":
            return f"{self.name}_csv"
        return self.name + units.SUFFIX.get(self.type, "")

    @property
    def sql_value(self) -> float | str | None:
        if self.type == "kinds":
            kinds = self.value if self.value is not None else VEHICLE_KINDS
            return "," + ",".join(kinds) + ","
        return self.value


@dataclass(frozen=True)
class Condition:
    """One per-frame condition of a phase: the boolean column, the measured value it tests, and the test."""

    name: str
    value: str
    test: str


@dataclass(frozen=True)
class Phase:
    """A phase: its query (or, for scenarios with a ``[match] frames`` query, the conditions of that query
    that make it hold), and the names of the time parameters that limit its duration (if any)."""

    name: str
    query: str | None
    min_duration: str | None = None
    max_duration: str | None = None
    conditions: tuple[Condition, ...] = ()


@dataclass(frozen=True)
class Kpi:
    name: str
    column: str
    unit: str
    description: str


@dataclass(frozen=True)
class CoverageItem:
    """A coverage item: numeric buckets ``[lo + k*every, lo + (k+1)*every)`` or an enum of values."""

    name: str
    column: str
    unit: str
    description: str
    sample: str  # "start" / "end" of the match interval, or "<phase>.start" / "<phase>.end"
    lo: float | None = None
    hi: float | None = None
    every: float | None = None
    values: tuple[str, ...] = ()


@dataclass(frozen=True)
class Scenario:
    name: str
    path: Path
    description: str
    spec: str
    version: int
    abstract: bool
    lineage: tuple[str, ...]  # this scenario and its bases, nearest first
    actors: dict[str, str]
    params: dict[str, Param]
    phases: tuple[Phase, ...]
    match_query: str | None
    frames_query: str | None  # one query giving every phase's per-frame conditions (phase_1 .. phase_n)
    junctions: bool  # the scenario needs the junction steps (queries/junctions/)
    kpi_queries: tuple[str, ...]
    kpis: tuple[Kpi, ...]
    coverage: tuple[CoverageItem, ...]
    overrides: dict[str, str] = field(default_factory=dict)

    def bindings(self) -> dict[str, float | str | None]:
        """SQL parameter name -> canonical value."""
        return {p.sql_name: p.sql_value for p in self.params.values()}

    def with_overrides(self, values: dict[str, str], where: str = "--set") -> Scenario:
        """A copy with parameter values replaced; ``values`` maps parameter name to text with unit."""
        params = dict(self.params)
        for name, text in values.items():
            if name not in params:
                raise ScenarioError(
                    f"{where} {name}={text}: scenario '{self.name}' has no parameter '{name}'."
                    f"{did_you_mean(name, list(params))}\n\nHint: `logiq-sql scenarios` lists every parameter."
                )
            p = params[name]
            params[name] = replace(p, text=text, value=_parse_value(p.type, text, f"{where} {name}={text}"))
        return replace(self, params=params, overrides={**self.overrides, **values})

    def params_hash(self) -> str:
        """Short digest of the scenario version and every bound value: same hash, same matches."""
        payload = json.dumps({"v": self.version, "p": self.bindings()}, sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _parse_value(type_: str, text: object, where: str) -> float | tuple[str, ...]:
    if type_ == "kinds":
        items = text if isinstance(text, list) else [s for s in str(text).replace(" ", "").split(",") if s]
        for kind in items:
            if kind not in OBJECT_KINDS:
                raise ScenarioError(
                    f"{where}: '{kind}' is not an evaluation_object_kind.{did_you_mean(kind, OBJECT_KINDS)}"
                    f"\n\nHint: use any of {', '.join(OBJECT_KINDS)}, comma-separated."
                )
        return tuple(items)
    return units.parse(text, type_, where)  # type: ignore[arg-type]


def scenario_files(directory: Path | None = None) -> dict[str, Path]:
    directory = directory or data_dir("scenarios")
    return {p.stem: p for p in sorted(directory.glob("*.toml"))}


def _read(path: Path) -> dict:
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML ({exc}).") from None
    unknown = set(raw) - _TOP_KEYS
    if unknown:
        key = sorted(unknown)[0]
        raise ScenarioError(f"{path}: unknown key '{key}'.{did_you_mean(key, sorted(_TOP_KEYS))}")
    if raw.get("name") != path.stem:
        raise ScenarioError(f"{path}: name = {raw.get('name')!r} must equal the file name '{path.stem}'.")
    return raw


def load_scenario(name_or_path: str | Path, directory: Path | None = None) -> Scenario:
    """Load a scenario by name (from ``scenarios/``) or path, resolving its bases.

    Raises:
        ScenarioError: unknown scenario or base, inheritance cycle, unknown key, bad parameter type or unit.
    """
    path = Path(name_or_path)
    if path.suffix == ".toml":
        directory = directory or path.parent
        name = path.stem
    else:
        name = str(name_or_path)
    files = scenario_files(directory)
    return _resolve(name, files, ())


def _resolve(name: str, files: dict[str, Path], chain: tuple[str, ...]) -> Scenario:
    if name in chain:
        cycle = " -> ".join((*chain, name))
        raise ScenarioError(f"{files[chain[0]]}: inheritance cycle {cycle}.\n\nHint: remove one `extends` entry.")
    if name not in files:
        where = f"{files[chain[-1]]}: extends" if chain else "scenario"
        raise ScenarioError(f"{where} '{name}' not found.{did_you_mean(name, list(files))}")
    path = files[name]
    raw = _read(path)
    bases = [_resolve(b, files, (*chain, name)) for b in raw.get("extends", [])]

    params: dict[str, Param] = {}
    kpi_queries: list[str] = []
    kpis: dict[str, Kpi] = {}
    coverage: dict[str, CoverageItem] = {}
    lineage: list[str] = [name]
    for base in bases:
        params.update(base.params)
        kpi_queries += [q for q in base.kpi_queries if q not in kpi_queries]
        kpis.update({k.name: k for k in base.kpis})
        coverage.update({c.name: c for c in base.coverage})
        lineage += [b for b in base.lineage if b not in lineage]

    for pname, spec in raw.get("params", {}).items():
        where = f"{path} [params.{pname}]"
        unknown = sorted(set(spec) - _PARAM_KEYS)  # a misspelt key would silently leave the default unset
        if unknown:
            raise ScenarioError(f"{where}: unknown key '{unknown[0]}'.{did_you_mean(unknown[0], sorted(_PARAM_KEYS))}"
                                f"\n\nHint: a parameter has {', '.join(sorted(_PARAM_KEYS))}.")
        type_ = spec.get("type")
        if type_ not in PARAM_TYPES:
            raise ScenarioError(f"{where}: type {type_!r} is not one of {', '.join(PARAM_TYPES)}.")
        default = spec.get("default")
        value = None if default is None else _parse_value(type_, default, f"{where} default")
        params[pname] = Param(pname, type_, None if default is None else str(default), value,
                              spec.get("description", ""), name)
    kpi_queries += [q for q in raw.get("kpi_queries", []) if q not in kpi_queries]
    for k in raw.get("kpis", []):
        kpis[k["name"]] = Kpi(k["name"], k["column"], k.get("unit", ""), k.get("description", ""))
    for c in raw.get("coverage", []):
        coverage[c["name"]] = _coverage_item(c, f"{path} [[coverage]] {c.get('name')}")

    phases = tuple(_phase(p, params, f"{path} [[phases]] {p.get('name')}") for p in raw.get("phases", []))
    abstract = bool(raw.get("abstract", False))
    match = raw.get("match", {}).get("query")
    frames = raw.get("match", {}).get("frames")
    if not abstract and (not phases or not match):
        raise ScenarioError(f"{path}: a concrete scenario needs [[phases]] and [match] query.")
    for phase in phases:
        if (phase.query is None) == (frames is None):
            raise ScenarioError(f"{path}: phase {phase.name} needs a query, unless [match] frames gives the "
                                "conditions of every phase (then no phase has its own query).")
    if frames and (len(phases) > 4 or any(p.min_duration or p.max_duration for p in phases)):
        raise ScenarioError(f"{path}: a scenario matched from [match] frames has at most 4 phases and no phase "
                            "duration limits (queries/match/sequential.sql).")
    if not abstract:
        _check_samples(coverage.values(), phases, path)
    return Scenario(
        name=name, path=path, description=raw.get("description", ""), spec=raw.get("spec", ""),
        version=int(raw.get("version", 1)), abstract=abstract, lineage=tuple(lineage),
        actors=dict(raw.get("actors", {})), params=params, phases=phases, match_query=match, frames_query=frames,
        junctions=bool(raw.get("junctions", False)),
        kpi_queries=tuple(kpi_queries), kpis=tuple(kpis.values()), coverage=tuple(coverage.values()),
    )


def _phase(p: dict, params: dict[str, Param], where: str) -> Phase:
    conditions = tuple(Condition(c["name"], c["value"], c["test"]) for c in p.get("conditions", []))
    phase = Phase(p["name"], p.get("query"), p.get("min_duration"), p.get("max_duration"), conditions)
    for limit in (phase.min_duration, phase.max_duration):
        if limit is not None and (limit not in params or params[limit].type != "time"):
            raise ScenarioError(f"{where}: duration limit '{limit}' must name a time parameter of the scenario."
                                f"{did_you_mean(limit, list(params))}")
    return phase


def _check_samples(items, phases: tuple[Phase, ...], path: Path) -> None:
    names = [p.name for p in phases]
    for item in items:
        phase = item.sample.rpartition(".")[0]
        if phase and phase not in names:
            raise ScenarioError(f"{path}: coverage item {item.name} is sampled at {item.sample!r}, but the "
                                f"scenario has no phase '{phase}'.{did_you_mean(phase, names)}")


def _coverage_item(c: dict, where: str) -> CoverageItem:
    sample = c.get("sample", "end")
    if sample.rpartition(".")[2] not in ("start", "end"):
        raise ScenarioError(f"{where}: sample must be 'start', 'end', '<phase>.start' or '<phase>.end', "
                            f"not {sample!r}.")
    if "values" in c:
        return CoverageItem(c["name"], c["column"], c.get("unit", ""), c.get("description", ""), sample,
                            values=tuple(c["values"]))
    lo, hi = c["range"]
    every = float(c["every"])
    if not (hi > lo and every > 0):
        raise ScenarioError(f"{where}: range must be [lo, hi] with hi > lo and every > 0.")
    return CoverageItem(c["name"], c["column"], c.get("unit", ""), c.get("description", ""), sample,
                        float(lo), float(hi), every)


def list_scenarios(directory: Path | None = None, include_abstract: bool = False) -> list[Scenario]:
    out = [load_scenario(n, directory) for n in scenario_files(directory)]
    return [s for s in out if include_abstract or not s.abstract]
