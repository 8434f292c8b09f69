"""Where the SQL and scenario files live: inside the wheel, or at the repo root in a checkout."""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parents[1]  # logiq_sql/ (this file is in logiq_sql/core/)


def data_dir(name: str) -> Path:
    """``queries/`` or ``scenarios/``: inside the installed package, else beside it (checkout, editable)."""
    for candidate in (_PKG / name, _PKG.parent / name):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"logiq_sql could not find its {name}/ folder in {_PKG} or {_PKG.parent}")


def query_path(relative: str) -> Path:
    """A built-in query (``phases/x.sql``), or a user's query file given by its absolute path."""
    path = Path(relative)
    return path if path.is_absolute() else data_dir("queries") / relative
