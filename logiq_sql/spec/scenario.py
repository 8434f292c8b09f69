"""Scenarios: declarative TOML files in ``scenarios/`` that name their SQL and declare parameters with units.

A scenario file may ``extends`` base scenarios. What it inherits:
- ``params``: every parameter of every base; the child may redeclare one to change its default.
- ``kpi_queries``, ``sample_queries``, ``kpis`` and ``coverage``: appended, bases first, each name once.
- ``phases`` (and the optional ``frames`` step they read): a concrete scenario declares its own, and so
  ``relation_kinds`` (the actor kinds its queries can use in ``relations``; unset: every kind) is its own too.

Every key of every table is checked here, at load (a misspelt key is an error with a did-you-mean); what the
SQL files use and return is checked against the scenario by ``logiq_sql.spec.contract`` before any data is read.
A scenario found in a user's folder (``--scenario-path DIR``) names its SQL files relative to its own folder,
else from the built-in ``queries/``; its bases may be built-in ones.

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

from logiq_sql.core import units
from logiq_sql.core.errors import ScenarioError, arg, did_you_mean
from logiq_sql.core.paths import data_dir, query_path
from logiq_sql.core.schema import OBJECT_KINDS, VEHICLE_KINDS

PARAM_TYPES = (*units.DIMENSIONS, "kinds")
_PARAM_KEYS = {"type", "default", "description"}
_TOP_KEYS = {
    "name", "description", "spec", "version", "abstract", "extends", "actors", "params", "phases",
    "frames", "kpi_queries", "sample_queries", "kpis", "coverage", "junctions", "relation_kinds",
}
_PHASE_KEYS = {"name", "description", "query", "min_duration", "max_duration", "conditions"}
_CONDITION_KEYS = {"name", "value", "test"}
_KPI_KEYS = {"name", "column", "unit", "type", "description"}
_COVERAGE_KEYS = {"name", "column", "unit", "sample", "description", "range", "every", "values"}
KPI_TYPES = ("number", "text")
# KPI units whose values are text; any other unit must be a unit of logiq_sql.core.units or declare `type`
TEXT_UNITS = ("string", "evaluation_object_kind")
# the table of a scenario's optional frames step, which its phase queries read by this name
FRAMES_TABLE = "scenario_frames"


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
    """A phase: its query of per-frame conditions (the phase contract, docs/scenarios.md), the conditions
    ``explain`` reports, and the names of the time parameters that limit its duration (if any)."""

    name: str
    query: str
    min_duration: str | None = None
    max_duration: str | None = None
    conditions: tuple[Condition, ...] = ()


@dataclass(frozen=True)
class Kpi:
    name: str
    column: str
    unit: str
    description: str
    type: str = "number"  # number (stored as double) or text (varchar)


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
    frames_query: str | None  # an optional step (table FRAMES_TABLE) that the phase queries read
    junctions: bool  # the scenario needs the junction steps (queries/junctions/)
    # the actor kinds whose rows of `relations` the scenario's queries can use (None: every kind); a run computes
    # the relation only for the kinds some scenario of it can use (logiq_sql.spec.plan.relation_kinds_csv)
    relation_kinds: tuple[str, ...] | None
    kpi_queries: tuple[str, ...]
    sample_queries: tuple[str, ...]  # one row per (match_id, sample): values at each sampling event
    kpis: tuple[Kpi, ...]
    coverage: tuple[CoverageItem, ...]
    overrides: dict[str, str] = field(default_factory=dict)

    def bindings(self) -> dict[str, float | str | None]:
        """SQL parameter name -> canonical value."""
        return {p.sql_name: p.sql_value for p in self.params.values()}

    def with_overrides(self, values: dict[str, str]) -> Scenario:
        """A copy with parameter values replaced; ``values`` maps parameter name to text with unit."""
        params = dict(self.params)
        for name, text in values.items():
            if name not in params:
                raise ScenarioError(
                    f"{arg('overrides', text, name)}: scenario '{self.name}' has no parameter '{name}'."
                    f"{did_you_mean(name, list(params))}\n\nHint: `logiq-sql scenarios` lists every parameter."
                )
            p = params[name]
            params[name] = replace(p, text=text, value=_parse_value(p.type, text, arg("overrides", text, name)))
        return replace(self, params=params, overrides={**self.overrides, **values})

    def metric_columns(self) -> dict[str, tuple[str, str, str]]:
        """Columns of ``kpis`` for this scenario: its KPIs, then its coverage samples -> (unit, SQL type,
        description)."""
        out = {k.column: (k.unit, "varchar" if k.type == "text" else "double",
                          f"{k.name} ({k.unit}): {k.description}") for k in self.kpis}
        for c in self.coverage:
            out.setdefault(c.column, (c.unit, "varchar" if c.values else "double",
                                      f"coverage item {c.name} ({c.unit}), sampled at the {c.sample}: {c.description}"))
        return out

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


ScenarioPath = Path | str | None  # a user's folder of scenarios (and their SQL), searched before the built-in one


def scenario_files(directory: ScenarioPath = None) -> dict[str, Path]:
    """Scenario name -> file: the built-in ``scenarios/``, then the user's folder (whose files win on a name
    they share)."""
    files = {p.stem: p for p in sorted(data_dir("scenarios").glob("*.toml"))}
    if directory is not None:
        folder = Path(directory)
        if not folder.is_dir():
            raise ScenarioError(f"{arg('scenario_path', folder)}: no such folder.")
        files.update({p.stem: p for p in sorted(folder.glob("*.toml"))})
    return files


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    if not isinstance(table, dict):
        raise ScenarioError(f"{where}: must be a table, not {table!r}.")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ScenarioError(f"{where}: unknown key '{unknown[0]}'.{did_you_mean(unknown[0], sorted(allowed))}"
                            f"\n\nHint: the keys here are {', '.join(sorted(allowed))} (docs/scenarios.md).")


def _required(table: dict, key: str, where: str) -> object:
    if key not in table:
        raise ScenarioError(f"{where}: missing key '{key}' (docs/scenarios.md).")
    return table[key]


def _read(path: Path) -> dict:
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML ({exc}).") from None
    _check_keys(raw, _TOP_KEYS, str(path))
    if raw.get("name") != path.stem:
        raise ScenarioError(f"{path}: name = {raw.get('name')!r} must equal the file name '{path.stem}'.")
    return raw


def _query_ref(path: Path, relative: str, where: str) -> str:
    """A query named in ``path``: beside the scenario file when it is there (a user's folder, as an absolute
    path), else in the built-in ``queries/``."""
    if not isinstance(relative, str) or not relative.endswith(".sql"):
        raise ScenarioError(f"{where}: {relative!r} must name a .sql file.")
    own = path.parent / relative
    if path.parent != data_dir("scenarios") and own.is_file():
        return str(own.resolve())
    if not query_path(relative).is_file():
        raise ScenarioError(f"{where}: query file {relative} not found beside {path.name} or in the built-in "
                            "queries/ folder.")
    return relative


def load_scenario(name_or_path: str | Path, directory: ScenarioPath = None) -> Scenario:
    """Load a scenario by name (from ``scenarios/`` and the user's ``directory``) or path, resolving its bases.

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
    sample_queries: list[str] = []
    kpis: dict[str, Kpi] = {}
    coverage: dict[str, CoverageItem] = {}
    lineage: list[str] = [name]
    relation_kinds = None  # not inherited: it describes what the scenario's own phase queries read
    for base in bases:
        params.update(base.params)
        kpi_queries += [q for q in base.kpi_queries if q not in kpi_queries]
        sample_queries += [q for q in base.sample_queries if q not in sample_queries]
        kpis.update({k.name: k for k in base.kpis})
        coverage.update({c.name: c for c in base.coverage})
        lineage += [b for b in base.lineage if b not in lineage]

    for pname, spec in raw.get("params", {}).items():
        where = f"{path} [params.{pname}]"
        _check_keys(spec, _PARAM_KEYS, where)  # a misspelt key would silently leave the default unset
        type_ = spec.get("type")
        if type_ not in PARAM_TYPES:
            raise ScenarioError(f"{where}: type {type_!r} is not one of {', '.join(PARAM_TYPES)}.")
        default = spec.get("default")
        value = None if default is None else _parse_value(type_, default, f"{where} default")
        params[pname] = Param(pname, type_, None if default is None else str(default), value,
                              spec.get("description", ""), name)
    for key in ("kpi_queries", "sample_queries"):
        own = [_query_ref(path, q, f"{path} {key}") for q in raw.get(key, [])]
        target = kpi_queries if key == "kpi_queries" else sample_queries
        target += [q for q in own if q not in target]
    for k in raw.get("kpis", []):
        kpi = _kpi(k, f"{path} [[kpis]] {_entry_name(k)}")
        kpis[kpi.name] = kpi
    for c in raw.get("coverage", []):
        where = f"{path} [[coverage]] {_entry_name(c)}"
        _check_keys(c, _COVERAGE_KEYS, where)
        coverage[_required(c, "name", where)] = _coverage_item(c, where)

    if "relation_kinds" in raw:
        relation_kinds = _relation_kinds(raw["relation_kinds"], f"{path} relation_kinds")
    phases = tuple(_phase(p, params, path, f"{path} [[phases]] {_entry_name(p)}") for p in raw.get("phases", []))
    abstract = bool(raw.get("abstract", False))
    frames = raw.get("frames")
    if frames is not None:
        frames = _query_ref(path, frames, f"{path} frames")
    if not abstract and not phases:
        raise ScenarioError(f"{path}: a concrete scenario needs [[phases]] (docs/scenarios.md).")
    names = [p.name for p in phases]
    if len(set(names)) != len(names):
        raise ScenarioError(f"{path}: two [[phases]] share a name; each phase needs its own.")
    if not abstract:
        _check_samples(coverage.values(), phases, path)
    return Scenario(
        name=name, path=path, description=raw.get("description", ""), spec=raw.get("spec", ""),
        version=int(raw.get("version", 1)), abstract=abstract, lineage=tuple(lineage),
        actors=dict(raw.get("actors", {})), params=params, phases=phases, frames_query=frames,
        junctions=bool(raw.get("junctions", False)), relation_kinds=relation_kinds,
        kpi_queries=tuple(kpi_queries), sample_queries=tuple(sample_queries), kpis=tuple(kpis.values()),
        coverage=tuple(coverage.values()),
    )


def _relation_kinds(value: object, where: str) -> tuple[str, ...]:
    """``relation_kinds = ["cyclist"]``: a non-empty list of evaluation_object_kinds."""
    if not isinstance(value, list) or not value or not all(isinstance(k, str) for k in value):
        raise ScenarioError(f"{where}: must be a non-empty list of kinds, e.g. [\"cyclist\"] (leave it out for "
                            "every kind).")
    return _parse_value("kinds", value, where)  # type: ignore[return-value]


def _entry_name(entry: object) -> str:
    """How an entry of an array of tables is named in messages: its name, else what it is."""
    return str(entry.get("name")) if isinstance(entry, dict) else repr(entry)


def _kpi(k: dict, where: str) -> Kpi:
    _check_keys(k, _KPI_KEYS, where)
    unit = k.get("unit", "")
    type_ = k.get("type")
    if type_ is None:
        if unit in TEXT_UNITS:
            type_ = "text"
        elif unit in units.UNITS or unit in ("", "mpsps"):
            type_ = "number"
        else:
            raise ScenarioError(f"{where}: unit {unit!r} is neither a unit of measure nor text; declare "
                                f"type = \"number\" or \"text\".")
    if type_ not in KPI_TYPES:
        raise ScenarioError(f"{where}: type {type_!r} is not one of {', '.join(KPI_TYPES)}."
                            f"{did_you_mean(str(type_), KPI_TYPES)}")
    return Kpi(_required(k, "name", where), _required(k, "column", where), unit, k.get("description", ""), type_)


def _phase(p: dict, params: dict[str, Param], path: Path, where: str) -> Phase:
    _check_keys(p, _PHASE_KEYS, where)
    conditions = []
    for c in p.get("conditions", []):
        _check_keys(c, _CONDITION_KEYS, f"{where} conditions")
        conditions.append(Condition(_required(c, "name", f"{where} conditions"),
                                    _required(c, "value", f"{where} conditions"), c.get("test", "")))
    query = _query_ref(path, _required(p, "query", where), f"{where} query")
    phase = Phase(_required(p, "name", where), query, p.get("min_duration"), p.get("max_duration"),
                  tuple(conditions))
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
    _required(c, "column", where)
    sample = c.get("sample", "end")
    if sample.rpartition(".")[2] not in ("start", "end"):
        raise ScenarioError(f"{where}: sample must be 'start', 'end', '<phase>.start' or '<phase>.end', "
                            f"not {sample!r}.")
    if "values" in c:
        return CoverageItem(c["name"], c["column"], c.get("unit", ""), c.get("description", ""), sample,
                            values=tuple(c["values"]))
    if "range" not in c or "every" not in c:
        raise ScenarioError(f"{where}: a numeric item needs range = [lo, hi] and every (an enum item: values).")
    lo, hi = c["range"]
    every = float(c["every"])
    if not (hi > lo and every > 0):
        raise ScenarioError(f"{where}: range must be [lo, hi] with hi > lo and every > 0.")
    return CoverageItem(c["name"], c["column"], c.get("unit", ""), c.get("description", ""), sample,
                        float(lo), float(hi), every)


def list_scenarios(directory: ScenarioPath = None, include_abstract: bool = False) -> list[Scenario]:
    out = [load_scenario(n, directory) for n in scenario_files(directory)]
    return [s for s in out if include_abstract or not s.abstract]
