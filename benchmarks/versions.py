"""Two versions of the code side by side in one benchmark run: a git revision's tree extracted to a folder, and
a child Python process that runs a script with one version's package on its path."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def checkout(revision: str, into: Path) -> Path:
    """The tree of git ``revision`` extracted into the folder ``into`` (created)."""
    into.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into


def run_child(code: Path, source: str, *args: str) -> dict:
    """``source`` run by this interpreter in a child process whose package is the tree ``code``; its last line of
    output, read as JSON."""
    out = subprocess.run([sys.executable, "-c", source, *args], check=True, capture_output=True, text=True,
                         cwd=code, env={"PYTHONPATH": str(code), "PATH": str(Path(sys.executable).parent)})
    return json.loads(out.stdout.strip().splitlines()[-1])
