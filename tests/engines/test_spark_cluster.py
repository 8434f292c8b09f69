"""A real Spark cluster: a standalone master and two workers, each its own JVM process on this machine, give the
same matches, phases, KPIs and coverage as DuckDB.

Marked ``spark_cluster``: part of ``make test`` (CI installs the [spark] extra; Java 17 is on the machines);
skipped without PySpark, except under CI=true, where it fails. The cluster is started from PySpark's own
``bin/spark-class`` (benchmarks/cluster.py, which the scale benchmark uses too), bound to 127.0.0.1 on free ports,
one core and 1 GiB per worker, and stopped in the fixture's teardown whatever happened. The driver is this
process; the executors (one per worker) are separate JVMs started by the workers, with their own Python workers.

The project ships to the executors as a user ships it to a cluster: ``pip wheel . --no-deps`` builds the wheel,
and the session adds it as a ``.zip`` Python file (``addPyFile``; Spark puts only .zip/.egg/.jar on the executors'
Python path, and a pure-Python wheel is a zip). The executors' Python (``$PYSPARK_PYTHON``) is this venv's,
which holds the dependencies (docs/engines.md: packing them for a cluster). The test checks that the executors
imported logiq_sql from the shipped zip, and that both workers' executors ran tasks (their own logs). The SUMO
junction goes from Parquet to Parquet, as a fleet's drives would: read from a dataset written by ``ingest
--dataset`` (the executors read it themselves), its results written by the executors under ``--out``
(logiq_sql/matching/spark_out.py). The scenarios' SQL on Spark, every scenario and the real drives, is test_spark.py's
(local mode): the same statements, so the cluster runs two scenarios of the junction, not all of them again."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import pytest
from test_spark import DATA, LEFT_TURN, OUTPUTS, assert_same_outputs, read_output

from logiq_sql import ingest, match
from logiq_sql.cli import EXIT_OK, main
from logiq_sql.ingestion.dataset_ingest import ingest_dataset

pytestmark = pytest.mark.spark_cluster
WORKERS = 2
WORKER_MEMORY = "1g"  # the executor (512m heap) must fit


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The project's wheel (benchmarks.cluster.project_zip), being built in a thread: pip spends most of its time
    fetching the build backend into its isolated environment (18 s of wall time for 4 s of CPU, measured), so it
    overlaps the cluster's JVM starts instead of following them. The same wheel, built the same way."""
    from benchmarks.cluster import project_zip

    with ThreadPoolExecutor(1) as pool:
        yield pool.submit(project_zip, tmp_path_factory.mktemp("dist"))


@pytest.fixture(scope="module")
def cluster(tmp_path_factory, client_jit, wheel):
    """spark://127.0.0.1:PORT of a running master with WORKERS registered workers, and the workers' folders."""
    try:
        import pyspark  # noqa: F401
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("CI=true but PySpark is not installed: pip install '.[spark]' (make venv does).")
        pytest.skip("PySpark is not installed: pip install 'logiq-sql[spark]' (needs Java 17).")
    from benchmarks.cluster import standalone

    # every JVM of the cluster (master, workers, executors) and the driver with the client JIT only (conftest.py)
    with standalone(tmp_path_factory.mktemp("cluster"), WORKERS, memory=WORKER_MEMORY) as running:
        yield running


@pytest.fixture(scope="module")
def session(cluster, wheel):
    """A Spark session on the cluster, configured as a user's script or notebook would configure it, with the
    project's wheel shipped to the executors."""
    from benchmarks.cluster import session as cluster_session

    url, _ = cluster
    patch = pytest.MonkeyPatch()  # cluster_session sets PYSPARK_PYTHON for the executors: undone afterwards
    patch.setenv("PYSPARK_PYTHON", os.environ.get("PYSPARK_PYTHON", ""))
    spark = cluster_session(url, wheel.result(), WORKERS)
    yield spark
    spark.stop()
    patch.undo()


def test_a_standalone_cluster_matches_like_duckdb(cluster, session, tmp_path):
    url, works = cluster
    assert session.sparkContext.master == url
    # the executors import the project from the shipped zip, not from this checkout
    where = set(session.sparkContext.parallelize(range(4), 4)
                .map(lambda _: __import__("logiq_sql").__file__).collect())
    assert where and all("logiq_sql.zip" in w for w in where), where

    # the SUMO junction from Parquet to Parquet: a dataset (ingest --dataset) the executors read themselves, the
    # encroachment areas (shapely) per drive on the executors (SparkEngine.derive), and the results written by
    # the executors as Parquet partitioned by scenario and drive (logiq_sql/matching/spark_out.py)
    sumo = [DATA / "sumo/junction_s1"]
    duck, folder, out = tmp_path / "sumo.duckdb", tmp_path / "sumo_dataset", tmp_path / "sumo_out"
    ingest("sumo", sumo, duck)
    ingest_dataset("sumo", sumo, folder)
    match(duck, scenarios=[LEFT_TURN, "follower_vehicle"], ego="every:40", keep=True)
    assert main(["match", "--dataset", str(folder), "--out", str(out), "--engine", "spark", "--spark-master", url,
                 "--scenario", LEFT_TURN, "--scenario", "follower_vehicle", "--ego", "every:40", "--keep",
                 "--quiet"]) == EXIT_OK
    kept = {"passages": ["drive_id", "actor_id", "passage"],
            "encroachments": ["drive_id", "ego_id", "ego_passage", "actor_id", "actor_passage"]}
    counts = dict(read_output(duck, "matches").group_by("scenario").len().rows())
    assert counts.keys() == {LEFT_TURN, "follower_vehicle"} and min(counts.values()) > 0, counts
    assert read_output(duck, "encroachments", kept["encroachments"]).height > 0
    assert_same_outputs(duck, out / "logiq.duckdb", {**OUTPUTS, **kept})
    written = {p.relative_to(out).parts[0] for p in out.rglob("part-*.parquet")}
    assert {"matches", "match_phases", "kpis", "coverage", "encroachments"} <= written, written

    from benchmarks.cluster import executor_task_lines

    ran = executor_task_lines(works)
    print(f"\ntasks run by the executors of each worker: {ran}")
    assert len(ran) == WORKERS and all(n > 0 for n in ran), ran

