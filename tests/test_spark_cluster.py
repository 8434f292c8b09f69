"""A real Spark cluster: a standalone master and two workers, each its own JVM process on this machine, give the
same matches, phases, KPIs and coverage as DuckDB.

Marked ``spark_cluster``: part of ``make test`` (CI installs the [spark] extra; Java 17 is on the machines);
skipped without PySpark, except under CI=true, where it fails. The cluster is started from PySpark's own
``bin/spark-class`` (org.apache.spark.deploy.master.Master and worker.Worker), bound to 127.0.0.1 on free ports,
one core and 1 GiB per worker, and stopped in the fixture's teardown whatever happened. The driver is this
process; the executors (one per worker) are separate JVMs started by the workers, with their own Python workers.

The project ships to the executors as a user ships it to a cluster: ``pip wheel . --no-deps`` builds the wheel,
and the session adds it as a ``.zip`` Python file (``addPyFile``; Spark puts only .zip/.egg/.jar on the executors'
Python path, and a pure-Python wheel is a zip). The executors' Python (``$PYSPARK_PYTHON``) is this venv's,
which holds the dependencies (docs/engines.md: packing them for a cluster). The test checks that the executors
imported logiq_sql from the shipped zip, and that both workers' executors ran tasks (their own logs). The SUMO
drive goes from Parquet to Parquet: read from a dataset written by ``ingest --dataset`` (the executors read it
themselves), its results written by the executors under ``--out`` (logiq_sql/spark_out.py)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_spark import DATA, LEFT_TURN, OUTPUTS, assert_same_outputs, match_both, read_output, twin_files

from logiq_sql import ingest, match
from logiq_sql.cli import EXIT_OK, main
from logiq_sql.dataset_ingest import ingest_dataset

pytestmark = pytest.mark.spark_cluster
ROOT = Path(__file__).resolve().parents[1]
WORKERS = 2
WORKER_MEMORY = "1g"  # the executor (512m heap) must fit
START_TIMEOUT_S = 180  # JVM starts on a busy 2-core machine


def _pyspark_home() -> Path:
    try:
        import pyspark
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("CI=true but PySpark is not installed: pip install '.[spark]' (make venv does).")
        pytest.skip("PySpark is not installed: pip install 'logiq-sql[spark]' (needs Java 17).")
    return Path(pyspark.__file__).parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(log: Path, text: str, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if log.exists() and text in log.read_text(errors="replace"):
            return
        if process.poll() is not None:
            raise RuntimeError(f"{log.name}: the process exited ({process.returncode}):\n{log.read_text()[-3000:]}")
        time.sleep(0.5)
    raise RuntimeError(f"{log.name}: no '{text}' after {START_TIMEOUT_S} s:\n{log.read_text()[-3000:]}")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """spark://127.0.0.1:PORT of a running master with WORKERS registered workers, and the workers' folders."""
    home = _pyspark_home()
    tmp = tmp_path_factory.mktemp("cluster")
    (tmp / "conf").mkdir()  # no spark-defaults.conf or log settings from the machine
    env = {**os.environ, "SPARK_HOME": str(home), "SPARK_LOCAL_IP": "127.0.0.1", "SPARK_CONF_DIR": str(tmp / "conf"),
           "SPARK_DAEMON_MEMORY": "256m", "PYSPARK_PYTHON": sys.executable}
    env.pop("PYSPARK_GATEWAY_PORT", None)
    spark_class = str(home / "bin/spark-class")
    port = _free_port()
    url = f"spark://127.0.0.1:{port}"
    processes: list[tuple[subprocess.Popen, object]] = []

    def start(name: str, *args: str) -> tuple[subprocess.Popen, Path]:
        log = tmp / f"{name}.log"
        out = log.open("w")
        process = subprocess.Popen([spark_class, *args], env=env, stdout=out, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        processes.append((process, out))
        return process, log

    try:
        master, master_log = start("master", "org.apache.spark.deploy.master.Master", "--host", "127.0.0.1",
                                   "--port", str(port), "--webui-port", str(_free_port()))
        _wait_for(master_log, "I have been elected leader", master)
        workers = []
        for i in range(WORKERS):
            work = tmp / f"worker{i}"
            work.mkdir()
            process, log = start(f"worker{i}", "org.apache.spark.deploy.worker.Worker", url, "--host", "127.0.0.1",
                                 "--port", str(_free_port()), "--webui-port", str(_free_port()), "--cores", "1",
                                 "--memory", WORKER_MEMORY, "--work-dir", str(work))
            workers.append((process, log, work))
        for process, log, _ in workers:
            _wait_for(log, "Successfully registered with master", process)
        yield url, [work for _, _, work in workers]
    finally:
        for process, out in reversed(processes):  # workers first, then the master
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
            out.close()


@pytest.fixture(scope="module")
def project_zip(tmp_path_factory) -> Path:
    """The project's wheel, as a user builds it, under a .zip name Spark puts on the executors' Python path."""
    dist = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(dist)],
                   check=True, cwd=dist)
    (wheel,) = dist.glob("logiq_sql-*.whl")
    return Path(shutil.copy(wheel, dist / "logiq_sql.zip"))


@pytest.fixture(scope="module")
def session(cluster, project_zip):
    """A Spark session on the cluster, configured as a user's script or notebook would configure it."""
    from pyspark.sql import SparkSession

    from logiq_sql.engines import spark_session

    url, _ = cluster
    # the executors' Python: PySpark reads it from $PYSPARK_PYTHON when the context starts (not from the conf)
    patch = pytest.MonkeyPatch()
    patch.setenv("PYSPARK_PYTHON", sys.executable)
    active = SparkSession.getActiveSession()
    if active is not None:  # a local session of another test module
        active.stop()
    (SparkSession.builder.master(url)
     .config("spark.driver.host", "127.0.0.1").config("spark.driver.bindAddress", "127.0.0.1")
     .config("spark.driver.memory", "1g").config("spark.executor.memory", "512m")
     .config("spark.executor.cores", "1").config("spark.cores.max", str(WORKERS))
     .config("spark.ui.enabled", "false").config("spark.ui.showConsoleProgress", "false")
     .config("spark.sql.shuffle.partitions", "4")
     .config("spark.sql.session.timeZone", "UTC")
     .config("spark.sql.sources.partitionColumnTypeInference.enabled", "false")
     .appName("logiq-sql cluster test").getOrCreate())
    spark = spark_session(url)  # the active session: what match(..., spark_master=url) will use
    spark.sparkContext.addPyFile(str(project_zip))
    yield spark
    spark.stop()
    patch.undo()


def _executor_task_lines(works: list[Path]) -> list[int]:
    """Per worker: how many tasks its executors logged as run (app-*/<executor id>/stderr)."""
    return [sum(log.read_text(errors="replace").count("Running task") for log in work.glob("app-*/*/stderr"))
            for work in works]


def test_a_standalone_cluster_matches_like_duckdb(cluster, session, tmp_path):
    url, works = cluster
    assert session.sparkContext.master == url
    # the executors import the project from the shipped zip, not from this checkout
    where = set(session.sparkContext.parallelize(range(4), 4)
                .map(lambda _: __import__("logiq_sql").__file__).collect())
    assert where and all("logiq_sql.zip" in w for w in where), where

    cr = DATA / "commonroad_ngsim/scenarios_2018b"
    nu = DATA / "nuscenes_mini_scenarionet"
    duck, spark_db = twin_files(tmp_path, "real", [("commonroad", [cr / "USA_US101-22_1_T-1.xml.gz"]),
                                              ("scenarionet", [nu / "sd_nuscenes_v1.0-mini_scene-0103.pkl"])])
    kwargs = dict(scenarios=["follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut"], ego="every:4",
                  overrides={"max_distance_from_cyclist": "6m"})
    match_both(duck, spark_db, spark_master=url, **kwargs)
    counts = read_output(duck, "matches").group_by("scenario").len().sort("scenario").rows()
    assert [s for s, n in counts if n > 0] == ["cyclist_close_to_moving_sut", "follower_vehicle", "sut_cut_out"]
    assert_same_outputs(duck, spark_db)

    # the SUMO junction from Parquet to Parquet: a dataset (ingest --dataset) the executors read themselves, the
    # encroachment areas (shapely) per drive on the executors (SparkEngine.derive), and the results written by
    # the executors as Parquet partitioned by scenario and drive (logiq_sql/spark_out.py)
    sumo = [DATA / "sumo/junction_s1"]
    duck, folder, out = tmp_path / "sumo.duckdb", tmp_path / "sumo_dataset", tmp_path / "sumo_out"
    ingest("sumo", sumo, duck)
    ingest_dataset("sumo", sumo, folder)
    match(duck, scenarios=[LEFT_TURN], ego="every:40", keep=True)
    assert main(["match", "--dataset", str(folder), "--out", str(out), "--engine", "spark", "--spark-master", url,
                 "--scenario", LEFT_TURN, "--ego", "every:40", "--keep", "--quiet"]) == EXIT_OK
    kept = {"passages": ["drive_id", "actor_id", "passage"],
            "encroachments": ["drive_id", "ego_id", "ego_passage", "actor_id", "actor_passage"]}
    assert read_output(duck, "matches").height > 0
    assert read_output(duck, "encroachments", kept["encroachments"]).height > 0
    assert_same_outputs(duck, out / "logiq.duckdb", {**OUTPUTS, **kept})
    written = {p.relative_to(out).parts[0] for p in out.rglob("part-*.parquet")}
    assert {"matches", "match_phases", "kpis", "coverage", "encroachments"} <= written, written

    ran = _executor_task_lines(works)
    print(f"\ntasks run by the executors of each worker: {ran}")
    assert len(ran) == WORKERS and all(n > 0 for n in ran), ran

