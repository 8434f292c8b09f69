"""Errors that name the file, the key or column, and the fix.

A message names the caller's argument with ``arg("overrides", "max_gap=4")``: Python callers read
``overrides['max_gap']='4'``-style names (``str(error)``), the command line reads its flag (``--set max_gap=4``,
``LogiqError.render`` with the CLI's table of flags). One message, two spellings of the argument.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping

_ARG = re.compile(r"\x00(\w+)\x01([^\x01\x02]*)\x01([^\x01\x02]*)\x01([^\x01\x02]*)\x02")


def arg(name: str, value: object = "", key: str = "") -> str:
    """The Python argument ``name`` (with the ``value`` the caller gave, and for a dict argument its ``key``) as it
    appears inside a message; rendered as ``name=value`` for Python and as the command-line flag by the CLI."""
    python = repr(value) if isinstance(value, int | float) else repr(str(value))  # a path reads as its text
    return f"\x00{name}\x01{key}\x01{value}\x01{python}\x02"


def _python(m: re.Match) -> str:
    name, key, value, python = m.groups()
    if key:
        return f"{name}[{key!r}]={python}"
    return f"{name}={python}" if value else f"{name}="


class SpeltArguments:
    """A message whose arguments (``arg``) read as Python names by default and as flags when the CLI renders it."""

    def render(self, flags: Mapping[str, str] | None = None) -> str:
        """The message; with ``flags`` (Python argument -> command-line flag) the arguments read as flags."""
        text = super().__str__()
        if flags is None:
            return _ARG.sub(_python, text)

        def flag(m: re.Match) -> str:
            name, key, value, _ = m.groups()
            spelt = flags.get(name, "--" + name.replace("_", "-"))
            return f"{spelt} {key}={value}" if key else f"{spelt} {value}".rstrip()

        return _ARG.sub(flag, text)

    def __str__(self) -> str:
        return self.render()


class LogiqError(SpeltArguments, ValueError):
    """Base of every error logiq_sql raises on bad input."""


class ScenarioError(LogiqError):
    """A scenario file or a parameter override is wrong."""


class UnitError(LogiqError):
    """A quantity has no unit, an unknown unit, or the wrong dimension."""


class InputError(LogiqError):
    """A data file cannot be trusted (missing columns, corrupt, unsafe)."""


class FileBusyError(SpeltArguments, RuntimeError):
    """Another run is writing the DuckDB file (it holds the writer lock): nothing was done."""


class DiskFullError(SpeltArguments, RuntimeError):
    """The disk filled up during a run: the run stopped and the published file is as it was."""


def did_you_mean(name: str, choices: list[str] | tuple[str, ...], cutoff: float = 0.6) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=cutoff)
    return f" Did you mean '{close[0]}'?" if close else ""
