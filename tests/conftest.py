"""Fixtures shared by test modules."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

# The JVMs of the Spark tests run many small, short jobs: the optimising JIT (C2) spends most of their CPU compiling
# code that runs for seconds. With the client JIT only, a local[2] match of one nuScenes scene took 53 s of CPU
# (driver and JVM, session start included) instead of 109 s, with the same results. The java launcher reads
# JDK_JAVA_OPTIONS, so it reaches every JVM started meanwhile: the local driver, and a standalone cluster's master,
# workers and (through the workers' environment) executors. Only the tests' JVMs: the engine's defaults stay.
CLIENT_JIT = "-XX:TieredStopAtLevel=1"

# `make test` runs the test files on two workers (pytest-xdist, `--dist loadfile --no-loadscope-reorder`), and
# xdist hands the files out in collection order: the longest files go first (wall times of a whole-suite run), so
# that no worker is left alone with one of them at the end. A plain `pytest` run takes the same order.
LONGEST_FIRST = ("test_spark_cluster.py", "test_spark.py", "test_notebooks.py", "test_sumo_evaluation.py",
                 "test_determinism.py", "test_analysts.py", "test_golden.py", "test_interrupted.py",
                 "test_interval_oracle.py", "test_concurrency.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


@pytest.fixture(scope="module")
def client_jit():
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("JDK_JAVA_OPTIONS", CLIENT_JIT)
        yield


class Ingested:
    """Bundled drives ingested once per session, handed out as copies.

    Many modules ingest the same bundled drives (the SUMO junction, NGSIM scenes, nuScenes, AV2) only to read or
    match them. ``ingested(dest, fmt, paths)`` ingests ``paths`` with ``fmt`` the first time it is asked (into a
    file of its own under the session's temporary folder) and copies that file to ``dest`` every time: each caller
    owns its copy and may match, re-ingest or otherwise write it without the others seeing. A published file has
    no WAL (db.Writer.publish checkpoints), so the .duckdb file is the whole state. Tests whose point is the ingest
    itself (bad input, interrupted or concurrent runs, accounting, determinism) still call ``ingest`` themselves.
    """

    def __init__(self, tmp_path_factory: pytest.TempPathFactory):
        self._tmp = tmp_path_factory
        self._built: dict[tuple, tuple[Path, list]] = {}

    def _build(self, steps: tuple) -> tuple[Path, list]:
        from logiq_sql.ingestion.ingest import ingest

        if steps not in self._built:
            path = self._tmp.mktemp("ingested") / "drives.duckdb"
            self._built[steps] = (path, [ingest(fmt, list(paths), path) for fmt, paths in steps])
        return self._built[steps]

    @staticmethod
    def _steps(steps) -> tuple:
        return tuple((fmt, tuple(Path(p).resolve() for p in paths)) for fmt, paths in steps)

    def steps(self, dest: Path, *steps: tuple[str, list]) -> Path:
        """A copy at ``dest`` of the file that the ingests ``(fmt, paths), ...`` give, in this order."""
        source, _ = self._build(self._steps(steps))
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, dest)
        return dest

    def __call__(self, dest: Path, fmt: str, paths: list) -> Path:
        """A copy at ``dest`` of ``paths`` ingested with ``fmt`` into an empty file."""
        return self.steps(dest, (fmt, paths))

    def summary(self, fmt: str, paths: list):
        """The IngestSummary of that one ingest (shared: read it, do not change it)."""
        return self._build(self._steps([(fmt, paths)]))[1][0]


@pytest.fixture(scope="session")
def ingested(tmp_path_factory) -> Ingested:
    return Ingested(tmp_path_factory)


@pytest.fixture(scope="session")
def matched_drives(tmp_path_factory) -> Path:
    """The drives docs/queries.md describes, ingested and matched once per session (tests.outputs.test_analysts.
    build_matched_db); test_analysts and test_replay each read their own copy."""
    from tests.outputs.test_analysts import build_matched_db

    return build_matched_db(tmp_path_factory.mktemp("matched_drives") / "drives.duckdb")
