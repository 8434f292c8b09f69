"""Ground-truth labels from SUMO records: exact definitions on hand-written runs, real properties on the fixtures."""

from __future__ import annotations

import ast
import gzip
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import shapely
import shapely.affinity

from logiq_sql.core.errors import InputError, ScenarioError
from logiq_sql.evaluation.labels import (
    LABEL_SCHEMA,
    LINK_SCHEMA,
    PATH_LANE_SCHEMA,
    SCENARIOS,
    box_corners,
    box_distance_m,
    conflict_zones,
    label_sumo,
    load_signals,
)
from logiq_sql.ingestion.readers.sumo import read_fcd, read_vtypes, xml_records
from tests.source_imports import logiq_imports, package_modules

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "tests/data/sumo"
MOTORWAY, JUNCTION = FIXTURES / "motorway_s1", FIXTURES / "junction_s1"
needs_fixtures = pytest.mark.skipif(not (MOTORWAY / "fcd.xml.gz").is_file() or not (JUNCTION / "fcd.xml.gz").is_file(),
                                    reason="SUMO fixtures tests/data/sumo/{motorway,junction}_s1 not present")
TYPES = ('<vType id="car" vClass="passenger" length="4.6" width="1.8"/>',
         '<vType id="bike" vClass="bicycle" length="1.6" width="0.65"/>')


def write_run(folder: Path, rows: list[dict], changes: list[tuple] = ()) -> Path:
    """A minimal SUMO run folder: routes with two vTypes, FCD of ``rows`` (see ``v``) and lanechange records
    ``(vehicle, time, from, to)``."""
    folder.mkdir(parents=True)
    (folder / "routes.rou.xml").write_text("<routes>\n" + "\n".join(TYPES) + "\n</routes>\n")
    lines = ["<fcd-export>"]
    for t in sorted({r["t"] for r in rows}):
        lines.append(f'    <timestep time="{t:.2f}">')
        for r in (r for r in rows if r["t"] == t):
            lines.append(
                f'        <vehicle id="{r["id"]}" type="{r["type"]}" x="{r["x"]:.2f}" y="{r["y"]:.2f}" '
                f'angle="{r["angle"]:.2f}" speed="{r["speed"]:.2f}" acceleration="0.00" lane="{r["lane"]}" '
                f'pos="0.00" leaderID="{r["leader"]}" leaderSpeed="-1.00" leaderGap="{r["gap"]:.2f}"/>')
        lines.append("    </timestep>")
    (folder / "fcd.xml").write_text("\n".join([*lines, "</fcd-export>", ""]))
    (folder / "lanechange.xml").write_text("\n".join(
        ["<lanechanges>", *(f'    <change id="{v}" type="car" time="{t:.2f}" from="{a}" to="{b}" dir="1"/>'
                            for v, t, a, b in changes), "</lanechanges>", ""]))
    return folder


def v(t: float, vid: str, x: float, speed: float, lane: str, kind: str = "car", y: float = 0.0,
      leader: str = "", gap: float = -1.0) -> dict:
    """One FCD vehicle row heading east (angle 90); x is the front bumper."""
    return {"t": t, "id": vid, "type": kind, "x": x, "y": y, "angle": 90.0, "speed": speed, "lane": lane,
            "leader": leader, "gap": gap}


def steps(t0: float, t1: float) -> list[float]:
    return [round(i * 0.1, 2) for i in range(round(t0 * 10), round(t1 * 10) + 1)]


def spans(labels: pl.DataFrame, scenario: str) -> list[tuple]:
    return [(r["ego_id"], r["actor_id"], round(r["start_s"], 2), round(r["end_s"], 2)) for r in
            labels.filter(pl.col("scenario") == scenario).sort("ego_id", "actor_id", "start_s").iter_rows(named=True)]


# ----------------------------------------------------------------------------------------- hand-written runs

def test_follower_islands_cut_at_the_ego_lane_change(tmp_path):
    rows = []
    for t in steps(0, 6):
        rows += [
            v(t, "E", 100 + 20 * t, 20, "e_0" if t < 2 else "e_1"),
            v(t, "A", 70 + 20 * t, 20, "e_0", leader="E" if t <= 5 else "", gap=25.4 if t <= 5 else -1),  # 1.27 s
            v(t, "B", 60 + 20 * t, 20, "e_0", kind="bike", leader="E", gap=20),  # a bicycle is no vehicle_actor
            v(t, "C", 20 * t, 20, "e_0", leader="E", gap=120),                    # 6 s: too far
            v(t, "D", 50 + 20 * t, 20, "e_0", leader="E" if t <= 0.9 else "", gap=20 if t <= 0.9 else -1),  # 0.9 s
        ]
    labels = label_sumo(write_run(tmp_path / "run", rows, [("E", 2.0, "e_0", "e_1")]), ["follower_vehicle"])
    # after E's lane change A stays on e_0 with SUMO's leader still E: not the same lane, so no label
    assert spans(labels, "follower_vehicle") == [("E", "A", 0.0, 1.9)]
    assert labels.schema == pl.Schema(LABEL_SCHEMA) and set(labels["drive_id"]) == {"run"}
    # the headway limit is a parameter: at most 1 s drops A (1.27 s) and keeps nobody
    tight = label_sumo(tmp_path / "run", ["follower_vehicle"], {"max_distance_from_sut_in_time_units": "1s"})
    assert tight.is_empty()


def test_follower_labels_bridge_a_gap_of_at_most_max_gap(tmp_path):
    """The matcher's gap rule, on the labels' side: SUMO names another leader for 0.5 s (5 frames at 10 Hz, as
    many as max_gap bridges) and A's episode goes on; 0.6 s (6 frames) ends it."""
    rows = []
    for t in steps(0, 6):
        a_lost = 2.0 <= t < 2.5           # 5 frames
        b_lost = 2.0 <= t < 2.6           # 6 frames
        rows += [
            v(t, "E", 100 + 20 * t, 20, "e_0"),
            v(t, "A", 75 + 20 * t, 20, "e_0", leader="" if a_lost else "E", gap=-1 if a_lost else 20),
            v(t, "F", 1100 + 20 * t, 20, "f_0"),
            v(t, "B", 1075 + 20 * t, 20, "f_0", leader="" if b_lost else "F", gap=-1 if b_lost else 20),
        ]
    labels = label_sumo(write_run(tmp_path / "run", rows), ["follower_vehicle"])
    assert spans(labels, "follower_vehicle") == [("E", "A", 0.0, 6.0), ("F", "B", 0.0, 1.9), ("F", "B", 2.6, 6.0)]
    exact = label_sumo(tmp_path / "run", ["follower_vehicle"], {"max_gap": "0s"})
    assert spans(exact, "follower_vehicle") == [("E", "A", 0.0, 1.9), ("E", "A", 2.5, 6.0),
                                                ("F", "B", 0.0, 1.9), ("F", "B", 2.6, 6.0)]


def test_a_follower_is_on_a_lane_the_ego_was_on(tmp_path):
    """SUMO's leader search follows the actor's route across a junction: a car waiting on its approach has as
    leader an ego that came from another approach onto the exit it will take. The spec's "same lane" does not."""
    rows = []
    for t in steps(0, 4):
        rows += [
            # E drives e_0 -> :C_0 (the junction, no lane change) -> w_0; A follows 1.25 s behind on the same lanes
            v(t, "E", 100 + 20 * t, 20, "e_0" if t < 1 else ":C_0" if t < 2 else "w_0"),
            v(t, "A", 75 + 20 * t, 20, "e_0" if t < 2.25 else ":C_0", leader="E", gap=25),
            # F approaches from another leg; SUMO gives E as its leader once E is on the exit F will take (2 s)
            v(t, "F", 5 * t, 5, "n_0", y=-30, leader="E" if t >= 2 else "", gap=10 if t >= 2 else -1),
        ]
    labels = label_sumo(write_run(tmp_path / "run", rows), ["follower_vehicle"])
    assert spans(labels, "follower_vehicle") == [("E", "A", 0.0, 4.0)]


def test_cut_out_phases_and_edge_boundary(tmp_path):
    rows, changes = [], [("E", 5.0, "e_0", "e_1"), ("A", 7.5, "f_0", "f_1"),
                         ("E2", 5.0, "e_0", "e_1"), ("E2", 5.5, "e_1", "e_2")]
    for t in steps(0, 9):
        # E follows A at 1 s headway, changes to e_1 at 5.0 s and moves on to edge f (lane f_1) at 7.0 s
        e_lane = "e_0" if t < 5 else ("e_1" if t < 7 else "f_1")
        a_lane = "e_0" if t < 6.5 else ("f_0" if t < 7.5 else "f_1")
        e2_lane = "e_0" if t < 5 else ("e_1" if t < 5.5 else "e_2")
        rows += [
            v(t, "E", 20 * t, 20, e_lane, leader="A" if t < 5 else "", gap=20 if t < 5 else -1),
            # A reaches edge f at 6.5 s, before E (lanes are compared on E's edge), and changes lanes at 7.5 s
            v(t, "A", 24.6 + 20 * t, 20, a_lane),
            # E2 changes twice: its second phase lasts 0.4 s
            v(t, "E2", 1000 + 20 * t, 20, e2_lane, leader="A2" if t < 5 else "", gap=20 if t < 5 else -1),
            v(t, "A2", 1024.6 + 20 * t, 20, "e_0"),
        ]
    labels = label_sumo(write_run(tmp_path / "run", rows, changes), ["sut_cut_out"])
    # phase 1: the last 3 s before the change (frames 1.9 .. 4.9); phase 2 from the change until A's lane change
    assert spans(labels, "sut_cut_out") == [("E", "A", 1.9, 7.4)]
    assert "e_0 -> e_1 at 5.0 s" in labels["source"][0]
    # phase 2 at most 2 s keeps its first 2 s
    short = label_sumo(tmp_path / "run", ["sut_cut_out"], {"max_ego_on_side_of_npc_phase_duration": "2s"})
    assert spans(short, "sut_cut_out") == [("E", "A", 1.9, 7.0)]


def test_cut_out_on_a_junction_lane_behind_an_actor_already_past_it(tmp_path):
    # E crosses junction j on its internal lane :j_0 behind A, which took another internal lane (:k_0) onto edge f
    # first; E changes to :j_1 at 5.0 s and comes out on f_1, beside A on f_0. A never drove E's edge :j, so
    # "beside" is read on A's edge: E's own lane there (f_1) against A's (f_0).
    rows, changes = [], [("E", 5.0, ":j_0", ":j_1")]
    for t in steps(0, 9):
        e_lane = ":j_0" if t < 5 else (":j_1" if t < 6 else "f_1")
        rows += [v(t, "E", 20 * t, 20, e_lane, leader="A" if t < 5 else "", gap=20 if t < 5 else -1),
                 v(t, "A", 24.6 + 20 * t, 20, ":k_0" if t < 2 else "f_0")]
    labels = label_sumo(write_run(tmp_path / "run", rows, changes), ["sut_cut_out"])
    assert spans(labels, "sut_cut_out") == [("E", "A", 1.9, 8.0)]


def test_cyclist_pieces_and_distance_band(tmp_path):
    rows = []
    for t in steps(0, 7):
        # boxes along +x: E's centre at 10 t, y 0; the bike's centre beside it 2 m to the left: gap 0.775 m
        rows += [
            v(t, "E", 10 * t + 2.3, 10, "e_0"),
            v(t, "C", 10 * t + 0.8, 10, "e_0", kind="bike", y=2.0),
            v(t, "C2", 10 * t + 0.8, 10, "e_0", kind="bike", y=8.0),  # 6.775 m
            v(t, "S", 502.3, 1.0, "e_0"),                              # below 5 kph
            v(t, "C3", 500.8, 0.0, "e_0", kind="bike", y=2.0),
        ]
    labels = label_sumo(write_run(tmp_path / "run", rows), ["cyclist_close_to_moving_sut"])
    assert spans(labels, "cyclist_close_to_moving_sut") == [("E", "C", 0.0, 5.0), ("E", "C", 5.1, 7.0)]
    wider = label_sumo(tmp_path / "run", ["cyclist_close_to_moving_sut"], {"max_distance_from_cyclist": "7m"})
    assert {r[1] for r in spans(wider, "cyclist_close_to_moving_sut")} == {"C", "C2"}


def test_an_episode_shorter_than_max_gap_is_no_label(tmp_path):
    """The matcher's jitter rule: a cyclist beside the ego for 0.3 s is a value dipping across a threshold."""
    rows = []
    for t in steps(0, 3):
        rows += [v(t, "E", 10 * t + 2.3, 10, "e_0"),
                 v(t, "C", 10 * t + 0.8, 10, "e_0", kind="bike", y=2.0 if 1.0 <= t <= 1.3 else 8.0)]
    labels = label_sumo(write_run(tmp_path / "run", rows), ["cyclist_close_to_moving_sut"])
    assert spans(labels, "cyclist_close_to_moving_sut") == []
    finer = label_sumo(tmp_path / "run", ["cyclist_close_to_moving_sut"], {"max_gap": "0.2s"})
    assert spans(finer, "cyclist_close_to_moving_sut") == [("E", "C", 1.0, 1.3)]


def test_box_distance_matches_shapely():
    rng = np.random.default_rng(7)
    n = 2000
    a = box_corners(rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n),
                    rng.uniform(0.5, 17, n), rng.uniform(0.4, 2.6, n))
    b = box_corners(rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n),
                    rng.uniform(0.5, 3, n), rng.uniform(0.4, 1, n))
    expected = shapely.distance(shapely.polygons(a), shapely.polygons(b))
    assert (expected == 0).sum() > 100 and (expected > 0).sum() > 100  # both cases are exercised
    np.testing.assert_allclose(box_distance_m(a, b), expected, atol=1e-9)


def test_errors_name_the_fix(tmp_path):
    with pytest.raises(ScenarioError, match="no labeller for scenario 'sut_cut_in'"):
        label_sumo(tmp_path, ["sut_cut_in"])
    with pytest.raises(ScenarioError, match="no labelled scenario has a parameter 'max_distance'"):
        label_sumo(tmp_path, ["follower_vehicle"], {"max_distance": "3m"})
    run = write_run(tmp_path / "run", [v(t, "E", t, 1, "e_0") for t in steps(0, 1)])
    (run / "lanechange.xml").unlink()
    with pytest.raises(InputError, match="no lane-change output file.*--lanechange-output"):
        label_sumo(run)


# ------------------------------------------------------------------------------------------- SUMO fixtures

@pytest.fixture(scope="module")
def fixture_labels() -> dict[str, pl.DataFrame]:
    return {run.name: label_sumo(run) for run in (MOTORWAY, JUNCTION)}


def _fcd(run: Path) -> pl.DataFrame:
    return read_fcd(run / "fcd.xml.gz").join(read_vtypes(run), on="type_id")


def _changes(run: Path) -> pl.DataFrame:
    return xml_records(run / "lanechange.xml.gz", "change", ("id", "time", "from", "to"), "</lanechanges>").select(
        ego_id="id", tc=pl.col("time").cast(pl.Float64))


@needs_fixtures
def test_fixture_label_counts(fixture_labels):
    counts = {run: dict(labels.group_by("scenario").len().iter_rows()) for run, labels in fixture_labels.items()}
    assert counts["motorway_s1"].get("follower_vehicle", 0) > 100 and counts["motorway_s1"].get("sut_cut_out", 0) > 10
    assert "cyclist_close_to_moving_sut" not in counts["motorway_s1"]  # no bicycles on the motorway
    assert counts["junction_s1"].get("cyclist_close_to_moving_sut", 0) > 10


def assert_holds_but_for_gaps(frames: pl.DataFrame, holds: pl.Expr) -> None:
    """Per label (column ``label``, frames by ``t_s``): ``holds`` is true at its first and last frame and false
    for at most max_gap (5 frames at 10 Hz) in a row: the labels bridge such gaps as the matcher does."""
    frames = frames.sort("label", "t_s").with_columns(holds=holds.fill_null(False))
    ends = frames.group_by("label").agg(first=pl.col("holds").first(), last=pl.col("holds").last())
    assert ends["first"].all() and ends["last"].all()
    lapses = frames.with_columns(lapse=pl.col("holds").rle_id().over("label")).filter(~pl.col("holds"))
    assert (lapses.group_by("label", "lapse").len()["len"].max() or 0) <= 5


@needs_fixtures
@pytest.mark.parametrize("run", [MOTORWAY, JUNCTION], ids=lambda p: p.name)
def test_fixture_followers_are_sumo_leaders(run, fixture_labels):
    labels = fixture_labels[run.name].filter(pl.col("scenario") == "follower_vehicle").with_row_index("label")
    fcd = _fcd(run)
    frames = labels.join(fcd, left_on="actor_id", right_on="vehicle_id").filter(
        pl.col("t_s").is_between(pl.col("start_s") - 1e-6, pl.col("end_s") + 1e-6))
    n_frames = ((labels["end_s"] - labels["start_s"]) * 10).round().cast(pl.Int64) + 1
    assert frames.height == n_frames.sum()  # every frame of every label is an FCD row of the actor
    # SUMO's leader is the ego at a label's first and last frame and at every other one but for interruptions of
    # at most max_gap (5 frames at 10 Hz), which the labels bridge as the matcher does
    headway = pl.col("leader_gap_m") / pl.col("speed_mps")
    assert_holds_but_for_gaps(frames, (pl.col("leader_id") == pl.col("ego_id")) & (pl.col("speed_mps") > 0)
                              & (headway >= 0) & (headway <= 5 + 1e-9))
    assert frames["kind"].is_in(["vehicle", "truck"]).all()
    assert (labels["end_s"] - labels["start_s"] >= 1 - 1e-9).all()
    # the ego keeps its lane: no lane change of the ego inside a label (after its first frame)
    inside = labels.join(_changes(run), on="ego_id").filter(
        (pl.col("tc") > pl.col("start_s") + 1e-6) & (pl.col("tc") <= pl.col("end_s") + 1e-6))
    assert inside.is_empty()


@needs_fixtures
@pytest.mark.parametrize("run", [MOTORWAY, JUNCTION], ids=lambda p: p.name)
def test_fixture_cut_outs_hold_an_ego_lane_change(run, fixture_labels):
    labels = fixture_labels[run.name].filter(pl.col("scenario") == "sut_cut_out").with_row_index("label")
    assert labels.height
    changes = labels.join(_changes(run), on="ego_id").filter(
        (pl.col("tc") >= pl.col("start_s") + 1 - 1e-6) & (pl.col("tc") <= pl.col("end_s") - 1 + 1e-6))
    assert changes["label"].n_unique() == labels.height  # phase 1 and phase 2 last at least 1 s around it
    assert (labels["end_s"] - labels["start_s"] <= 6.1 + 1e-9).all()
    fcd = _fcd(run).select("t_s", "vehicle_id", "leader_id", "lane_id")
    # just before the change the ego's SUMO leader is the actor; at the change the ego is on another lane
    first = changes.sort("label", "tc").unique("label", keep="first")
    before = first.join(fcd, left_on=["ego_id", (pl.col("tc") - 0.1).round(2)], right_on=["vehicle_id", "t_s"])
    assert before.height == labels.height and (before["leader_id"] == before["actor_id"]).all()
    at = (first.join(fcd, left_on=["ego_id", "tc"], right_on=["vehicle_id", "t_s"])
          .join(fcd, left_on=["actor_id", "tc"], right_on=["vehicle_id", "t_s"], suffix="_actor"))
    assert at.height == labels.height and (at["lane_id"] != at["lane_id_actor"]).all()


@needs_fixtures
def test_fixture_cyclist_distances_recomputed_with_shapely(fixture_labels):
    labels = fixture_labels["junction_s1"].filter(pl.col("scenario") == "cyclist_close_to_moving_sut")
    assert (labels["end_s"] - labels["start_s"] <= 5 + 1e-9).all()
    sample = labels.sample(n=min(40, labels.height), seed=1).with_row_index("label")
    fcd = _fcd(JUNCTION)
    frames = (sample.join(fcd, left_on="ego_id", right_on="vehicle_id")
              .filter(pl.col("t_s").is_between(pl.col("start_s") - 1e-6, pl.col("end_s") + 1e-6))
              .join(fcd, left_on=["actor_id", "t_s"], right_on=["vehicle_id", "t_s"], suffix="_c"))
    assert frames["vclass_c"].eq("bicycle").all() and frames["vclass"].ne("bicycle").all()

    def boxes(suffix: str) -> np.ndarray:
        h = np.radians(90.0 - frames["angle_deg" + suffix].to_numpy())
        length, width = frames["length_m" + suffix].to_numpy(), frames["width_m" + suffix].to_numpy()
        cx = frames["x_m" + suffix].to_numpy() - length / 2 * np.cos(h)
        cy = frames["y_m" + suffix].to_numpy() - length / 2 * np.sin(h)
        return np.array([shapely.affinity.rotate(shapely.box(x - l / 2, y - w / 2, x + l / 2, y + w / 2),
                                                 math.degrees(a), origin=(x, y))
                         for x, y, a, l, w in zip(cx, cy, h, length, width, strict=True)])

    distance = shapely.distance(boxes(""), boxes("_c"))
    assert len(distance) > 40
    assert_holds_but_for_gaps(frames.with_columns(distance_m=distance),
                              (pl.col("distance_m") <= 5 + 1e-6) & (pl.col("speed_mps") >= 5 / 3.6 - 1e-9))


# ------------------------------------------------------------ unprotected_left_turn_with_yield_and_traffic_light

LEFT_TURN = "unprotected_left_turn_with_yield_and_traffic_light"


def _net(run: Path) -> ET.Element:
    return ET.fromstring(gzip.decompress((run / "network.net.xml.gz").read_bytes()))


def _signalised_paths(run: Path) -> pl.DataFrame:
    """Per signalised connection of the network, read here with ElementTree: its dir, link index, incoming and
    outgoing edge, and its internal lanes in order with the offset of each from the stop line."""
    root = _net(run)
    length = {lane.get("id"): float(lane.get("length")) for lane in root.iter("lane")}
    onward = {f"{c.get('from')}_{c.get('fromLane')}": c.get("via") for c in root.iter("connection")
              if c.get("from").startswith(":")}
    rows = []
    for c in root.iter("connection"):
        if c.get("tl") is None:
            continue
        lane, start = c.get("via"), 0.0
        while lane:
            rows.append((c.get("dir"), int(c.get("linkIndex")), c.get("from"), c.get("to"), lane, start,
                         length[lane]))
            start += length[lane]
            lane = onward.get(lane)
    frame = pl.DataFrame(rows, orient="row", schema=["dir", "link_index", "from_edge", "to_edge", "lane_id",
                                                     "start_m", "length_m"])
    return frame.with_columns(total_m=pl.col("length_m").sum().over("link_index")).drop("length_m")


def _offsets(run: Path) -> pl.DataFrame:
    """FCD rows with the vehicle's connection through the junction (its first internal lane's) and its box
    centre's offset from the stop line along that connection (lane position - length / 2)."""
    paths = _signalised_paths(run)
    incoming = {lane.get("id"): float(lane.get("length")) for edge in _net(run).iter("edge")
                if edge.get("to") == "C" for lane in edge.iter("lane")}
    fcd = _fcd(run).sort("vehicle_id", "t_s")
    link = (fcd.join(paths.select("lane_id", "link_index"), on="lane_id")
            .group_by("vehicle_id").agg(pl.col("link_index").first()))
    edge = pl.col("lane_id").str.extract(r"^(.*)_\d+$")
    return (fcd.join(link, on="vehicle_id")
            .join(paths.select("link_index", "dir", "from_edge", "to_edge", "total_m").unique(), on="link_index")
            .join(paths.select("lane_id", "start_m"), on="lane_id", how="left")
            .with_columns(front_m=pl.when(pl.col("start_m").is_not_null())
                          .then(pl.col("start_m") + pl.col("lane_pos_m"))
                          .when(edge == pl.col("from_edge"))
                          .then(pl.col("lane_pos_m") - pl.col("lane_id").replace_strict(incoming, default=None))
                          .when(edge == pl.col("to_edge")).then(pl.col("total_m") + pl.col("lane_pos_m")))
            .with_columns(centre_m=pl.col("front_m") - pl.col("length_m") / 2))


def left_turn_label_rows(labels: pl.DataFrame) -> tuple[pl.DataFrame, pl.DataFrame, pl.DataFrame]:
    """The junction fixture's FCD offsets (``_offsets``), its ego rows (columns prefixed e_), and each left-turn
    label with the ego's (e_*) and the actor's (a_*) rows and the signal state string at its start."""
    rows = _offsets(JUNCTION)
    states = xml_records(JUNCTION / "tls_states.xml.gz", "tlsState", ("time", "state"), "</tlsStates>").select(
        t_s=pl.col("time").cast(pl.Float64), state="state")
    ego = rows.rename(lambda c: c if c in ("vehicle_id", "t_s") else f"e_{c}")
    actor = rows.rename(lambda c: c if c in ("vehicle_id", "t_s") else f"a_{c}")
    at_start = (labels.join(ego, left_on=["ego_id", "start_s"], right_on=["vehicle_id", "t_s"])
                .join(actor, left_on=["actor_id", "start_s"], right_on=["vehicle_id", "t_s"])
                .join(states, left_on="start_s", right_on="t_s"))
    return rows, ego, at_start


@needs_fixtures
def test_fixture_left_turns_hold_in_sumo_lanes_and_signals(fixture_labels):
    labels = fixture_labels["junction_s1"].filter(pl.col("scenario") == LEFT_TURN)
    assert labels.height >= 20
    rows, ego, at_start = left_turn_label_rows(labels)
    assert at_start.height == labels.height
    # the ego turns left through the signalised junction (its internal lanes are those of a dir="l" connection)
    assert at_start["e_dir"].is_in(["l", "L"]).all() and at_start["e_kind"].eq("vehicle").all()
    # a vehicle from another incoming edge; both within 10 m of their stop lines, box front by lane position
    assert at_start["a_kind"].eq("vehicle").all()
    assert (at_start["a_from_edge"] != at_start["e_from_edge"]).all()
    for who in ("e", "a"):
        assert at_start[f"{who}_front_m"].is_between(-10 - 1e-6, 10 + 1e-6).all()
    # the ego is stopped (<= 2 kph) on green: character link_index of SUMO's state string is G or g
    assert (at_start["e_speed_mps"] <= 2 / 3.6 + 1e-9).all()
    signal = at_start.select(pl.col("state").str.slice(pl.col("e_link_index"), 1))["state"]
    assert signal.is_in(["G", "g"]).all()
    # the interval ends at the ego's last step with its front inside the junction; it then leaves, after the actor
    span = rows.group_by("vehicle_id").agg(first_s=pl.col("t_s").min(), last_s=pl.col("t_s").max())
    at_end = labels.join(ego, left_on=["ego_id", "end_s"], right_on=["vehicle_id", "t_s"])
    after = labels.join(ego, left_on=["ego_id", (pl.col("end_s") + 0.1).round(1)], right_on=["vehicle_id", "t_s"])
    assert at_end.height == after.height == labels.height
    assert ((at_end["e_front_m"] >= 0) & (at_end["e_front_m"] < at_end["e_total_m"])).all()
    assert (after["e_front_m"] >= after["e_total_m"]).all()
    out = rows.filter(pl.col("front_m") >= pl.col("total_m")).group_by("vehicle_id").agg(out_s=pl.col("t_s").min())
    order = labels.join(out, left_on="ego_id", right_on="vehicle_id").join(
        out, left_on="actor_id", right_on="vehicle_id", suffix="_actor")
    assert order.height == labels.height and (order["out_s_actor"] < order["out_s"]).all()
    within = labels.join(span, left_on="ego_id", right_on="vehicle_id")
    assert ((within["first_s"] <= within["start_s"]) & (within["start_s"] <= within["end_s"])
            & (within["end_s"] < within["last_s"])).all()


@needs_fixtures
def test_conflict_zones_are_sumo_foes():
    """Every pair of paths whose car-wide areas cross is a pair SUMO's own right-of-way table (the junction's
    <request foes>) calls foes; each crossing lies inside both paths."""
    links, path_lanes, _ = load_signals(JUNCTION)
    zones = conflict_zones(links, path_lanes, [1.8], [1.8])
    assert zones.height >= 20
    (junction,) = [j for j in _net(JUNCTION).iter("junction") if j.get("id") == "C"]
    foes = {(int(r.get("index")), i) for r in junction.iter("request")
            for i, bit in enumerate(reversed(r.get("foes"))) if bit == "1"}
    index = dict(zip(links["link"], links["link_index"], strict=True))
    assert all((index[a], index[b]) in foes for a, b in zones.select("link", "link_f").iter_rows())
    total = dict(zip(links["link"], links["total_m"], strict=True))
    for side in ("", "_f"):
        ends = zones.select(lo=f"enter_m{side}", hi=f"leave_m{side}",
                            total=pl.col(f"link{side}").replace_strict(total))
        assert ((ends["lo"] >= -1e-6) & (ends["lo"] < ends["hi"]) & (ends["hi"] <= ends["total"] + 1e-6)).all()


@needs_fixtures
def test_cli_label_then_evaluate_end_to_end(tmp_path, capsys, ingested):
    from logiq_sql.cli import build_parser
    from logiq_sql.evaluation.evaluate import evaluate
    from logiq_sql.matching.match import match

    parser = build_parser()
    out = tmp_path / "labels.parquet"
    args = parser.parse_args(["label", "sumo", str(JUNCTION), "--out", str(out)])
    assert args.func(args) == 0
    labels = pl.read_parquet(out)
    assert f"{labels.height} label(s) of 1 run(s)" in capsys.readouterr().out
    assert labels.schema == pl.Schema(LABEL_SCHEMA)
    db = ingested(tmp_path / "j.duckdb", "sumo", [JUNCTION])
    match(db, scenarios=list(SCENARIOS), ego="every:4")  # the labelled ones (others would be all FP)
    result = evaluate(db, out)
    assert set(result.scores["scenario"]) == set(SCENARIOS)
    events = result.events.group_by("scenario", "role").len()
    assert events["len"].sum() == result.scores["labels"].sum() + result.scores["predictions"].sum()
    for col in ("precision", "recall", "f1", "ba_timestamp", "tpr", "tnr"):
        assert result.scores[col].drop_nulls().is_between(0, 1).all()
    assert any("the matcher did not use" in n for n in result.notes)


# --------------------------------------------------------------------------------------- independence (13.7)

def _imports_closure(module: str) -> set[str]:
    """Every logiq_sql module ``module`` imports, directly or through others, at any level (read from the
    source: tests/source_imports.py)."""
    trees = package_modules()
    seen, todo = set(), [module]
    while todo:
        name = todo.pop()
        if name in seen or name not in trees:
            continue
        seen.add(name)
        todo += [m for m, _ in logiq_imports(ast.walk(trees[name]), set(trees))]
    return seen - {module}


MATCHER_MODULES = {"logiq_sql.matching.match", "logiq_sql.core.sql", "logiq_sql.matching.explain", "logiq_sql.engines",
                   "logiq_sql.ingestion.localise", "logiq_sql.matching.encroachment", "logiq_sql.ingestion.ingest", "logiq_sql.storage.db",
                   "logiq_sql.spec.plan", "logiq_sql.matching.runner", "logiq_sql.storage.store", "logiq_sql.spec.contract"}  # the split matcher


def test_the_labeller_never_imports_the_matcher():
    closure = _imports_closure("logiq_sql.evaluation.labels")
    assert "logiq_sql.ingestion.readers.sumo" in closure  # the walk sees the labeller's real imports
    assert not closure & MATCHER_MODULES, closure & MATCHER_MODULES
    assert not any(m.startswith("logiq_sql.matching.match") for m in closure)  # nor a split matcher package
    text = (Path(__file__).resolve().parents[2] / "logiq_sql/evaluation/labels.py").read_text()
    assert ".sql" not in text and "queries" not in text  # nor reads a query file itself


def test_the_evaluation_harness_does_not_import_the_cli():
    for name in ("simulate", "labels", "evaluate", "crosscheck"):
        closure = _imports_closure(f"logiq_sql.evaluation.{name}")
        assert "logiq_sql.cli" not in closure, name


def _crossing_network() -> tuple[pl.DataFrame, pl.DataFrame]:
    """(links, path_lanes) as load_signals gives them for a junction [-10, 10]^2 with one light C: link C:0 turns
    left from the south (a quarter circle of radius 11.75 m about (-10, -10)), link C:1 goes straight from the
    north (x = -1.75). Approaches 200 m long; the exits' lanes start where each path ends."""
    a = np.linspace(0, np.pi / 2, 50)
    arc = np.column_stack([-10 + 11.75 * np.cos(a), -10 + 11.75 * np.sin(a)])
    straight = np.array([[-1.75, 10.0], [-1.75, -10.0]])
    rows, lanes = [], []
    for index, (shape, d, src, dst) in enumerate(((arc, "l", "S", "W"), (straight, "s", "N", "Sx"))):
        length = float(np.linalg.norm(np.diff(shape, axis=0), axis=1).sum())
        rows.append((f"C:{index}", "C", index, d, src, dst, length, shape.ravel().tolist()))
        lanes += [(f"C:{index}", f":C_{index}_0", 0.0, length, length), (f"C:{index}", f"{src}_0", -200.0, None, None),
                  (f"C:{index}", f"{dst}_0", length, None, None)]
    return (pl.DataFrame(rows, orient="row", schema=LINK_SCHEMA),
            pl.DataFrame(lanes, orient="row", schema=PATH_LANE_SCHEMA))


def _on_path(vid: str, t: np.ndarray, front: np.ndarray, link: int, src: str, dst: str, total: float) -> pl.DataFrame:
    """FCD-like rows of a car whose front is ``front`` metres past its stop line (SUMO lane and position)."""
    lane = np.where(front < 0, f"{src}_0", np.where(front < total, f":C_{link}_0", f"{dst}_0"))
    pos = np.where(front < 0, 200 + front, np.where(front < total, front, front - total))
    speed = np.abs(np.gradient(front, t))
    return pl.DataFrame({"vehicle_id": vid, "frame": np.round(t * 10).astype(np.int64), "t_s": t, "lane_id": lane,
                         "lane_pos_m": pos, "speed_mps": np.where(speed < 1e-9, 0.0, speed), "kind": "vehicle",
                         "length_m": 4.5, "width_m": 1.8})


def test_the_left_turn_label_is_not_the_car_before_one_that_came_in_the_amber():
    """The ego waits 3 m into the junction on green; a car from the north crosses its path at 4-6.7 s while the
    light is green; the light turns amber at 10 s and red at 13 s; a second car, near its stop line only after
    the green, crosses 11.5-14.2 s; the ego sets off at 13.5 s as it clears, to leave the junction. The ego
    waited for the second car (the last to reach its path before it set off), which it did not stand for on
    green: no occurrence (docs/semantics.md, phase 3 and "A red in between"; the matcher and the conflict
    labeller agree). Looking for the last car only among the cars that approached on green, the phase labeller
    credited the first car, which passed 7 s before the ego moved (SUMO, junction_skew15_cycle60 seed 972,
    car_S_left.5: a truck in the amber)."""
    from logiq_sql.evaluation.conflict_labels import candidates
    from logiq_sql.evaluation.labels import scenario_values, unprotected_left_turn_with_yield_and_traffic_light

    links, path_lanes = _crossing_network()
    total = dict(links.select("link", "total_m").rows())
    t = np.round(np.arange(0, 250) * 0.1, 6)
    go = np.clip(t - 13.5, 0, None)
    rows = pl.concat([
        _on_path("ego", t, 3.0 + go**2, 0, "S", "W", total["C:0"]),
        _on_path("first", t, 10 * (t - 4.0), 1, "N", "Sx", total["C:1"]),
        _on_path("second", t, 10 * (t - 11.5), 1, "N", "Sx", total["C:1"]),
    ])
    states = pl.DataFrame({"tl": "C", "t_s": [0.0, 10.0, 13.0], "state": ["GG", "yy", "rr"]})
    p = scenario_values([LEFT_TURN])[LEFT_TURN]
    found = unprotected_left_turn_with_yield_and_traffic_light(rows, links, path_lanes, states, p, 0.1)
    events = candidates(rows, links, path_lanes, states, p, 0.1)
    # the drive is what the docstring says: both cars cross the ego's path first, the second one is the car the
    # ego waited for, and it came near its stop line only after the green
    assert events.filter(pl.col("crossed")).height == 2
    assert events.filter("waited_for")["actor_id"].to_list() == ["second"]
    assert found.is_empty(), found
