"""What every command of ``logiq-sql`` shares, product and harness alike: exit codes, the epilog, the options
several commands take (--db, --set, --wait, ...), and how a command's parser is made."""

from __future__ import annotations

import argparse
import os

from logiq_sql.core.errors import LogiqError
from logiq_sql.core.schema import EGO_KINDS
from logiq_sql.spec.plan import DEFAULT_RELATION_RANGE

# exit codes a scheduler can act on
EXIT_OK = 0  # done (also when the reader of the output closed the pipe early, as `| head` does)
EXIT_UNEXPECTED = 1  # a bug or an environment failure: the traceback says where
EXIT_BAD_INPUT = 2  # nothing was done: the message names the file, key or column and the fix
EXIT_REJECTED = 3  # ingest finished, but some drives were rejected (their reasons are in the drives table)
EXIT_BUSY = 4  # nothing was done: another run is writing the file (the message names it); retry or --wait
EXIT_DISK_FULL = 5  # the disk filled up: the run stopped, the file is as the last completed run left it
EPILOG = ("Docs: README.md and docs/ in the repository. Exit codes: 0 done, 1 unexpected failure, 2 bad input, "
          "3 ingest done but some drives rejected, 4 another run is writing the file, 5 disk full.")
DB_ENV = "LOGIQ_SQL_DB"  # the default of --db on every command that takes one


def set_pairs(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise LogiqError(f"--set {item}: write NAME=VALUE with a unit, e.g. --set max_distance_from_cyclist=4m.")
        out[name.strip()] = value.strip()
    return out


def db_of(args: argparse.Namespace) -> str:
    """--db, else $LOGIQ_SQL_DB."""
    db = args.db or os.environ.get(DB_ENV)
    if not db:
        raise LogiqError(f"{args.command}: no DuckDB file given: pass --db FILE or set {DB_ENV}=FILE.")
    return db


def add_db(p: argparse.ArgumentParser, what: str = "DuckDB file written by ingest and match") -> None:
    p.add_argument("--db", metavar="FILE", help=f"{what} (default: ${DB_ENV})")


def add_set(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override a parameter, with its unit (e.g. max_distance_from_cyclist=4m)")


def add_wait(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wait", type=float, default=0.0, metavar="SECONDS",
                   help="when another run is writing the file, wait up to this long for it (a progress line every "
                        "10 s) instead of stopping at once with exit code 4 (default 0)")


def add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", action="store_true", help="no progress lines (the summary and exit code stay)")


def add_relation_range(p: argparse.ArgumentParser) -> None:
    p.add_argument("--relation-range", default=DEFAULT_RELATION_RANGE, metavar="LENGTH",
                   help="keep ego-actor pairs whose centres are at most this far apart "
                        f"(default {DEFAULT_RELATION_RANGE}: a 5 s headway at 140 km/h)")


def add_scenario_path(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario-path", metavar="DIR",
                   help="a folder of your own scenario files (and their SQL), besides the built-in ones; they may "
                        "extend the built-in bases (docs/scenarios.md)")


def add_ego_kinds(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ego-kinds", metavar="KINDS",
                   help="the kinds that can be the SUT for --ego auto, all and every:N, comma-separated (default "
                        f"{','.join(EGO_KINDS)}; car means vehicle)")


def command(sub, name: str, func, help: str, description: str | None = None,
             hidden: bool = False) -> argparse.ArgumentParser:
    """A command's parser; a ``hidden`` one is left out of the command list (argparse lists only those with help)."""
    listed = {} if hidden else {"help": help}
    p = sub.add_parser(name, description=description or help[0].upper() + help[1:] + ".", epilog=EPILOG, **listed)
    p.set_defaults(func=func, renamed=f"eval {name}" if hidden else None)
    return p
