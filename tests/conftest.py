"""Fixtures shared by test modules."""

from __future__ import annotations

import pytest

# The JVMs of the Spark tests run many small, short jobs: the optimising JIT (C2) spends most of their CPU compiling
# code that runs for seconds. With the client JIT only, a local[2] match of one nuScenes scene took 53 s of CPU
# (driver and JVM, session start included) instead of 109 s, with the same results. The java launcher reads
# JDK_JAVA_OPTIONS, so it reaches every JVM started meanwhile: the local driver, and a standalone cluster's master,
# workers and (through the workers' environment) executors. Only the tests' JVMs: the engine's defaults stay.
CLIENT_JIT = "-XX:TieredStopAtLevel=1"


@pytest.fixture(scope="module")
def client_jit():
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("JDK_JAVA_OPTIONS", CLIENT_JIT)
        yield
