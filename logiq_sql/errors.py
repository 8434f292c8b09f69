"""Errors that name the file, the key or column, and the fix."""

from __future__ import annotations

import difflib


class LogiqError(ValueError):
    """Base of every error logiq_sql raises on bad input."""


class ScenarioError(LogiqError):
    """A scenario file or a --set override is wrong."""


class UnitError(LogiqError):
    """A quantity has no unit, an unknown unit, or the wrong dimension."""


class InputError(LogiqError):
    """A data file cannot be trusted (missing columns, corrupt, unsafe)."""


class FileBusyError(RuntimeError):
    """Another run is writing the DuckDB file (it holds the writer lock): nothing was done."""


class DiskFullError(RuntimeError):
    """The disk filled up during a run: the run stopped and the published file is as it was."""


def did_you_mean(name: str, choices: list[str] | tuple[str, ...], cutoff: float = 0.6) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=cutoff)
    return f" Did you mean '{close[0]}'?" if close else ""
