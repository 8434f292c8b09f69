"""Quantities with units: parsed once, at load time, into the canonical unit of their dimension.

Canonical units (the suffix every column and SQL parameter carries):

| dimension    | canonical | suffix  | accepted spellings                          |
|--------------|-----------|---------|---------------------------------------------|
| length       | metre     | `_m`    | m, meter, meters, metre, km, cm, ft, mi     |
| time         | second    | `_s`    | s, sec, second, seconds, ms, min             |
| speed        | m/s       | `_mps`  | mps, m/s, kph, km/h, kmh, mph, fps          |
| acceleration | m/s^2     | `_mps2` | mpsps, mps2, m/s^2, m/s2, g                 |
| number       | (none)    |         | a bare number (fractions such as 0.25)      |
"""

from __future__ import annotations

import re

from logiq_sql.core.errors import UnitError

# unit spelling -> (dimension, factor to the canonical unit)
UNITS: dict[str, tuple[str, float]] = {
    "m": ("length", 1.0), "meter": ("length", 1.0), "meters": ("length", 1.0),
    "metre": ("length", 1.0), "metres": ("length", 1.0), "km": ("length", 1000.0),
    "cm": ("length", 0.01), "ft": ("length", 0.3048), "mi": ("length", 1609.344),
    "s": ("time", 1.0), "sec": ("time", 1.0), "second": ("time", 1.0), "seconds": ("time", 1.0),
    "ms": ("time", 0.001), "min": ("time", 60.0),
    "mps": ("speed", 1.0), "m/s": ("speed", 1.0), "kph": ("speed", 1 / 3.6),
    "km/h": ("speed", 1 / 3.6), "kmh": ("speed", 1 / 3.6), "mph": ("speed", 0.44704),
    "fps": ("speed", 0.3048),
    "mpsps": ("acceleration", 1.0), "mps2": ("acceleration", 1.0), "m/s^2": ("acceleration", 1.0),
    "m/s2": ("acceleration", 1.0), "g": ("acceleration", 9.80665),
}

CANONICAL: dict[str, str] = {"length": "m", "time": "s", "speed": "mps", "acceleration": "mps2"}
SUFFIX: dict[str, str] = {"length": "_m", "time": "_s", "speed": "_mps", "acceleration": "_mps2"}
# The spec writes types as "length", "time", "speed"; "float" is a plain number.
DIMENSIONS = (*CANONICAL, "number")

_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z/^0-9]*)\s*$")


def parse(text: str | float | int, dimension: str, where: str) -> float:
    """Read ``text`` as a quantity of ``dimension`` and return it in the canonical unit.

    Args:
        text: e.g. ``"4m"``, ``"5 kph"``, ``"1sec"``, ``0.25`` (numbers only for dimension "number").
        dimension: one of ``DIMENSIONS``.
        where: the file and key, or the flag, quoted in errors.

    Raises:
        UnitError: no unit where one is needed, an unknown unit, or a unit of another dimension.
    """
    if isinstance(text, bool):
        raise UnitError(f"{where}: expected a {dimension}, got {text!r}.")
    if isinstance(text, int | float):
        if dimension == "number":
            return float(text)
        raise UnitError(
            f"{where}: {text!r} has no unit; a {dimension} needs one.\n\n"
            f"Hint: write it with a unit, e.g. \"{text} {CANONICAL[dimension]}\"."
        )
    match = _QUANTITY.match(str(text))
    if not match:
        raise UnitError(
            f"{where}: cannot read {text!r} as a quantity.\n\n"
            f"Hint: write a number and a unit, e.g. \"30 kph\", \"4m\", \"1.5s\"."
        )
    value, unit = float(match.group(1)), match.group(2)
    if dimension == "number":
        if unit:
            raise UnitError(f"{where}: {text!r} must be a plain number, without a unit.")
        return value
    if not unit:
        raise UnitError(
            f"{where}: {text!r} has no unit; a {dimension} needs one.\n\n"
            f"Hint: write it with a unit, e.g. \"{value:g} {CANONICAL[dimension]}\"."
        )
    if unit.lower() not in UNITS and unit not in UNITS:
        known = ", ".join(u for u, (d, _) in UNITS.items() if d == dimension)
        raise UnitError(f"{where}: unknown unit {unit!r} in {text!r}.\n\nHint: a {dimension} takes one of: {known}.")
    found_dim, factor = UNITS.get(unit, UNITS.get(unit.lower(), ("", 0.0)))
    if found_dim != dimension:
        raise UnitError(
            f"{where}: {text!r} is a {found_dim}, but this parameter is a {dimension}.\n\n"
            f"Hint: use a {dimension} unit such as {CANONICAL[dimension]!r}."
        )
    return value * factor


def factor(unit: str) -> float:
    """How many canonical units one ``unit`` is (e.g. ``factor("mph") == 0.44704``)."""
    try:
        return UNITS[unit][1]
    except KeyError:
        raise UnitError(f"unknown unit {unit!r}") from None
