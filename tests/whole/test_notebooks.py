"""The notebooks in notebooks/ run top to bottom on the bundled data and draw their pictures (executed copies go to
a temporary folder; the committed notebooks have no outputs)."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"


RUN = ["quickstart.ipynb", "exploration.ipynb", "frames.ipynb"]


@pytest.fixture(scope="module")
def executed() -> dict[str, nbformat.NotebookNode | BaseException]:
    """Every notebook, executed at the same time: each in its own kernel (process), all driven by one event loop
    (nbclient's async_execute). They share nothing (each writes to its own temporary folder), and on 2 cores the
    kernels' start-up and single-threaded Python overlap; each test below checks its own notebook's outputs, and
    a notebook that fails to run fails its own test with the error."""
    async def run(name: str) -> nbformat.NotebookNode:
        nb = nbformat.read(NOTEBOOKS / name, as_version=4)
        await NotebookClient(nb, timeout=300, kernel_name="python3",
                             resources={"metadata": {"path": str(NOTEBOOKS)}}).async_execute()
        return nb

    async def run_all() -> list:
        return await asyncio.gather(*(run(name) for name in RUN), return_exceptions=True)

    with pytest.MonkeyPatch.context() as patch:
        # the kernels import logiq_sql from this checkout, whatever is installed in the environment
        patch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        return dict(zip(RUN, asyncio.run(run_all())))


def execute(name: str, tmp_path: Path, executed) -> nbformat.NotebookNode:
    nb = executed[name]
    if isinstance(nb, BaseException):
        raise nb
    nbformat.write(nb, tmp_path / name)  # the executed copy, as a reader would open it
    return nb


def outputs(nb: nbformat.NotebookNode, kind: str) -> list[str]:
    """Every output of the given MIME type (image/png, text/plain, or 'stream' for printed text)."""
    found = []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            if kind == "stream" and out.output_type == "stream":
                found.append(out.text)
            elif kind in out.get("data", {}):
                found.append(out.data[kind])
    return found


def replays(nb: nbformat.NotebookNode) -> list[str]:
    """The HTML outputs that are matplotlib animations (replays) with their frames."""
    return [h for h in outputs(nb, "text/html") if 'class="anim-state"' in h]


@pytest.mark.parametrize("name", RUN)
def test_committed_notebooks_have_no_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    assert [c for c in nb.cells if c.cell_type == "code" and (c.outputs or c.execution_count)] == []


def test_quickstart(tmp_path, executed):
    nb = execute("quickstart.ipynb", tmp_path, executed)
    printed = "".join(outputs(nb, "stream"))
    assert "3 drive(s) ingested, 0 rejected" in printed and "4 drive(s) ingested, 0 rejected" in printed
    assert "unprotected_left_turn_with_yield_and_traffic_light: 10 matches in 1 drive(s)" in printed
    assert "sut_cut_out:" in printed
    assert len(outputs(nb, "image/png")) == 2  # the cut-out timeline and the follower coverage
    assert len(replays(nb)) == 1  # a cut-out
    assert any("matches_per_scenario" in t for t in outputs(nb, "text/html"))


def test_exploration(tmp_path, executed):
    nb = execute("exploration.ipynb", tmp_path, executed)
    images = outputs(nb, "image/png")
    # timeline, a bird's-eye view, a coverage grid per scenario (found in scenarios/), KPI grid
    from logiq_sql.spec.scenario import list_scenarios
    assert len(images) == 2 + len(list_scenarios()) + 1
    # the motorway cut-out, then one match of each scenario, each with its frames
    assert len(replays(nb)) == 1 + len(list_scenarios()) and all(r.count("data:image/png;base64") >= 10 for r in replays(nb))
    printed = "".join(outputs(nb, "stream"))
    assert all(s in printed for s in ("follower_vehicle", "sut_cut_out", "cyclist_close_to_moving_sut",
                                      "unprotected_left_turn_with_yield_and_traffic_light"))
    tables = "".join(outputs(nb, "text/html"))
    assert "pet_between_sut_and_npc_s" in tables and "empty_buckets" in tables


def test_frames(tmp_path, executed):
    nb = execute("frames.ipynb", tmp_path, executed)
    printed = "".join(outputs(nb, "stream"))
    assert "53,089 track rows, 1,307 lanes, 4 drives" in printed
    assert "follower_vehicle: 4 matches in 3 drive(s)" in printed and "cyclist_close_to_moving_sut: 1 matches" in printed
    assert "sut_cut_out: ran" in printed
    assert "unprotected_left_turn_with_yield_and_traffic_light cannot run without junctions" in printed
    assert "follower_vehicle cannot run without lanes" in printed  # the LazyFrame without a map
    assert "tracks: missing column 'x_m'. Did you mean 'x'?" in printed
    assert "actors move at a median 1,038 m/s between samples" in printed
    assert len(outputs(nb, "image/png")) == 2  # the timeline and the follower coverage
