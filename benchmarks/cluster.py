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


def project_zip(folder: Path, root: Path = ROOT) -> Path:
    """The project's wheel (of the source tree ``root``), as a user builds it, under a .zip name Spark puts on the
    executors' Python path."""
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(root), "--no-deps", "-q", "-w", str(folder)],
                   check=True, cwd=folder)
    (wheel,) = folder.glob("logiq_sql-*.whl")
    return Path(shutil.copy(wheel, folder / "logiq_sql.zip"))


def session(url: str, shipped: Path, executors: int, executor_memory: str = "512m", driver_memory: str = "1g",
            event_log: Path | None = None):
    """A Spark session on the cluster at ``url``, configured as a user's script or notebook would configure it,
    with ``shipped`` (project_zip) on the executors' Python path; one core per executor; Spark's event log (every
    job's, stage's and task's times and metrics, as JSON lines) written to the folder ``event_log`` if given."""
    from pyspark.sql import SparkSession

    from logiq_sql.engines.spark_engine import spark_session

    os.environ["PYSPARK_PYTHON"] = sys.executable  # read when the context starts (not from the conf)
    active = SparkSession.getActiveSession()
    if active is not None:  # a local session of this process
        active.stop()
    builder = SparkSession.builder
    try:  # the JVM options the code under test asks for (benchmarks/spark_cluster.py runs older revisions too)
        from logiq_sql.engines.spark_engine import session_options
    except ImportError:
        pass
    else:
        builder = builder.config(map=session_options())
    if event_log is not None:
        event_log.mkdir(parents=True, exist_ok=True)
        builder = (builder.config("spark.eventLog.enabled", "true").config("spark.eventLog.dir", event_log.as_uri())
                   .config("spark.eventLog.compress", "false").config("spark.eventLog.rolling.enabled", "false"))
    (builder.master(url)
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


class TreeCPU:
    """CPU seconds of this process's descendants (the cluster's JVMs, the executors and their Python workers, a
    child driver and its JVM), sampled from /proc every ``interval_s`` in a thread. ``between(start, end)`` is
    what they spent between two monotonic times, each process counted with its last sample (one that ended between
    two samples loses at most ``interval_s`` of its time); ``executors=True``: only the executors' JVMs
    (CoarseGrainedExecutorBackend) and their Python workers."""

    def __init__(self, interval_s: float = 0.5):
        import threading

        self._tick = os.sysconf("SC_CLK_TCK")
        self._cpu: dict[int, float] = {}
        self._executor: set[int] = set()
        self._series: list[tuple[float, float, float]] = []  # (monotonic time, all, executors)
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(interval_s,), daemon=True)
        self._thread.start()

    def _stat(self) -> dict[int, tuple[int, float]]:
        seen = {}
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    with open(f"/proc/{entry}/stat") as f:
                        fields = f.read().rsplit(")", 1)[1].split()
                except OSError:
                    continue
                seen[int(entry)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / self._tick)
        return seen

    def _run(self, interval_s: float) -> None:
        me = os.getpid()
        while True:
            now, seen = time.monotonic(), self._stat()
            ours = {me}
            for _ in range(10):  # descendants, whatever order /proc lists them in
                ours |= {pid for pid, (parent, _) in seen.items() if parent in ours}
            for pid in ours - {me}:
                if pid not in self._cpu:
                    parent = seen[pid][0]
                    try:
                        with open(f"/proc/{pid}/cmdline", "rb") as f:
                            executor = b"CoarseGrainedExecutorBackend" in f.read()
                    except OSError:
                        executor = False
                    if executor or parent in self._executor:
                        self._executor.add(pid)
                self._cpu[pid] = seen[pid][1]
            self._series.append((now, sum(self._cpu.values()),
                                 sum(cpu for pid, cpu in self._cpu.items() if pid in self._executor)))
            if self._done.wait(interval_s):
                return

    def between(self, start: float, end: float, executors: bool = False) -> float:
        def total(t: float) -> float:
            before = [s for s in self._series if s[0] <= t]
            return before[-1][2 if executors else 1] if before else 0.0
        return total(end) - total(start)

    def stop(self) -> None:
        self._done.set()
        self._thread.join()


def match_in_child(code: Path, url: str, shipped: Path, dataset: Path, out: Path, ego: str, executors: int,
                   executor_memory: str, event_log: Path) -> dict:
    """``match_dataset(dataset, out, engine="spark")`` on the cluster at ``url`` by a driver in a child process
    that imports logiq_sql from the source tree ``code`` (and ships ``shipped``, that tree's wheel): two versions
    of the code on one cluster, one input. Its wall and CPU seconds (that process's), and the monotonic times the
    match started and ended (for TreeCPU)."""
    result = out.with_name(out.name + ".json")
    args = [str(code), url, str(shipped), str(dataset), str(out), ego, str(executors), executor_memory,
            str(event_log), str(result)]
    subprocess.run([sys.executable, "-m", "benchmarks.cluster", *args], check=True, cwd=ROOT,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    import json

    return json.loads(result.read_text())


def _child(code: str, url: str, shipped: str, dataset: str, out: str, ego: str, executors: str, executor_memory: str,
           event_log: str, result: str) -> None:
    import json

    sys.path.insert(0, code)  # logiq_sql from that tree; benchmarks (already imported) from this one
    from logiq_sql.core.timing import cpu_seconds, recording
    from logiq_sql.matching.match import match_dataset

    assert Path(sys.modules["logiq_sql"].__file__).is_relative_to(Path(code).resolve()), sys.modules["logiq_sql"]
    spark = session(url, Path(shipped), int(executors), executor_memory=executor_memory, driver_memory="4g",
                    event_log=Path(event_log))
    try:
        with recording() as stages:
            start, cpu = time.monotonic(), cpu_seconds()
            match_dataset(dataset, out, ego=ego, engine="spark", spark_master=url)
            end, cpu = time.monotonic(), cpu_seconds() - cpu
    finally:
        spark.stop()
    Path(result).write_text(json.dumps({
        "seconds": end - start, "driver_python_cpu_seconds": cpu, "start": start, "end": end,
        "stages": {name: {"seconds": s, "driver_python_cpu_seconds": stages.cpu_seconds[name]}
                   for name, s in stages.seconds.items()}}))


if __name__ == "__main__":
    _child(*sys.argv[1:])
