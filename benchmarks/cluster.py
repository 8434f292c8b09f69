"""A Spark standalone cluster on this machine, as a user would run one: a master and N workers, each its own JVM
started from PySpark's own ``bin/spark-class`` (org.apache.spark.deploy.master.Master and worker.Worker), bound to
127.0.0.1 on free ports, and a session on it with the project shipped to the executors as a wheel.

Used by the cluster test (tests/engines/test_spark_cluster.py) and the scale benchmark (benchmarks/spark_cluster.py).

The project ships as a user ships it: ``pip wheel . --no-deps`` builds the wheel, and the session adds it as a
``.zip`` Python file (``addPyFile``; Spark puts only .zip/.egg/.jar on the executors' Python path, and a
pure-Python wheel is a zip). The executors' Python (``$PYSPARK_PYTHON``) is this interpreter, which holds the
dependencies (docs/engines.md: packing them for a real cluster).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 180  # JVM starts on a busy 2-core machine


def pyspark_home() -> Path:
    import pyspark

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


@contextmanager
def standalone(folder: Path, workers: int, cores: int = 1, memory: str = "1g") -> Iterator[tuple[str, list[Path]]]:
    """spark://127.0.0.1:PORT of a running master with ``workers`` registered workers (``cores`` and ``memory``
    each), and the workers' folders (their executors' logs); every process is stopped on the way out, whatever
    happened."""
    home = pyspark_home()
    (folder / "conf").mkdir(parents=True, exist_ok=True)  # no spark-defaults.conf or log settings of the machine
    env = {**os.environ, "SPARK_HOME": str(home), "SPARK_LOCAL_IP": "127.0.0.1",
           "SPARK_CONF_DIR": str(folder / "conf"), "SPARK_DAEMON_MEMORY": "256m", "PYSPARK_PYTHON": sys.executable}
    env.pop("PYSPARK_GATEWAY_PORT", None)
    spark_class = str(home / "bin/spark-class")
    url = f"spark://127.0.0.1:{_free_port()}"
    processes: list[tuple[subprocess.Popen, object]] = []

    def start(name: str, *args: str) -> tuple[subprocess.Popen, Path]:
        log = folder / f"{name}.log"
        out = log.open("w")
        process = subprocess.Popen([spark_class, *args], env=env, stdout=out, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        processes.append((process, out))
        return process, log

    try:
        master, master_log = start("master", "org.apache.spark.deploy.master.Master", "--host", "127.0.0.1",
                                   "--port", url.rsplit(":", 1)[1], "--webui-port", str(_free_port()))
        _wait_for(master_log, "I have been elected leader", master)
        started = []
        for i in range(workers):
            work = folder / f"worker{i}"
            work.mkdir(exist_ok=True)
            process, log = start(f"worker{i}", "org.apache.spark.deploy.worker.Worker", url, "--host", "127.0.0.1",
                                 "--port", str(_free_port()), "--webui-port", str(_free_port()), "--cores", str(cores),
                                 "--memory", memory, "--work-dir", str(work))
            started.append((process, log, work))
        for process, log, _ in started:
            _wait_for(log, "Successfully registered with master", process)
        yield url, [work for _, _, work in started]
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


def project_zip(folder: Path) -> Path:
    """The project's wheel, as a user builds it, under a .zip name Spark puts on the executors' Python path."""
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w", str(folder)],
                   check=True, cwd=folder)
    (wheel,) = folder.glob("logiq_sql-*.whl")
    return Path(shutil.copy(wheel, folder / "logiq_sql.zip"))


def session(url: str, shipped: Path, executors: int, executor_memory: str = "512m", driver_memory: str = "1g"):
    """A Spark session on the cluster at ``url``, configured as a user's script or notebook would configure it,
    with ``shipped`` (project_zip) on the executors' Python path; one core per executor."""
    from pyspark.sql import SparkSession

    from logiq_sql.engines.spark_engine import spark_session

    os.environ["PYSPARK_PYTHON"] = sys.executable  # read when the context starts (not from the conf)
    active = SparkSession.getActiveSession()
    if active is not None:  # a local session of this process
        active.stop()
    (SparkSession.builder.master(url)
     .config("spark.driver.host", "127.0.0.1").config("spark.driver.bindAddress", "127.0.0.1")
     .config("spark.driver.memory", driver_memory).config("spark.executor.memory", executor_memory)
     .config("spark.executor.cores", "1").config("spark.cores.max", str(executors))
     .config("spark.ui.enabled", "false").config("spark.ui.showConsoleProgress", "false")
     .config("spark.sql.shuffle.partitions", "4")
     .config("spark.sql.session.timeZone", "UTC")
     .config("spark.sql.sources.partitionColumnTypeInference.enabled", "false")
     .appName("logiq-sql").getOrCreate())
    spark = spark_session(url)  # the active session: what match(..., spark_master=url) will use
    spark.sparkContext.addPyFile(str(shipped))
    return spark


def executor_task_lines(works: list[Path]) -> list[int]:
    """Per worker: how many tasks its executors logged as run (app-*/<executor id>/stderr)."""
    return [sum(log.read_text(errors="replace").count("Running task") for log in work.glob("app-*/*/stderr"))
            for work in works]
