"""Simulated drives from Eclipse SUMO: a motorway or a signalised junction, built and run with SUMO's own tools.

Why: SUMO writes, beside the trajectories, its own answers (lane changes, TTC/DRAC/PET conflicts, signal states,
collisions) that serve as an independent reference for the scenarios found in the tracks. The network is written
as plain node/edge/connection XML and built by ``netconvert``; the demand is flows of vehicle types with a vClass,
length and width, routed by ``sumo`` itself at departure; the run is at 0.1 s steps with a fixed seed, so the same
command gives the same trajectories. The output names are fixed (``OUTPUTS``): the SUMO reader and the
ground-truth labeller rely on them. See docs/sumo.md.

SUMO is an optional extra (``pip install 'logiq-sql[sumo]'``); its binaries are found through the ``sumo``
package (``sumo.SUMO_HOME/bin``), never on PATH.
"""

from __future__ import annotations

import math
import shlex
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from logiq_sql.core.errors import LogiqError
from logiq_sql.evaluation.perceive import Noise, perceive
from logiq_sql.ingestion.readers.sumo import sumo_bin

KINDS = ("motorway", "junction")
STEP_S = 0.1
# SSM logs an encounter when TTC < 5 s, DRAC > 3 m/s^2 or PET < 2 s. 5 s rather than SUMO's 3 s: with
# collision-free Krauss drivers few encounters go below 3 s, and the TTC cross-check needs car-following pairs.
SSM_THRESHOLDS = "5.0 3.0 2.0"
WARMUP_S = 60
# file name -> what it holds; the reader and the labeller rely on these names
OUTPUTS = {
    "network.net.xml.gz": "the network (netconvert)",
    "routes.rou.xml": "vehicle types (vClass, length, width) and flows",
    "fcd.xml.gz": "trajectories every 0.1 s: front bumper x/y, angle, speed, acceleration, lane, leader",
    "lanechange.xml.gz": "every lane change with its reason and gaps (evaluation only)",
    "ssm.xml.gz": "SSM conflicts: TTC < 5 s, DRAC > 3 m/s^2, PET < 2 s (evaluation only)",
    "tls_states.xml.gz": "signal state of every traffic light at every step (junction only)",
    "tripinfo.xml.gz": "one summary per finished trip (evaluation only)",
    "collisions.xml.gz": "collisions SUMO detected (evaluation only)",
    "sumo.log": "SUMO's warnings, e.g. emergency braking (evaluation only)",
    "cmd.txt": "the exact commands run, the SUMO version and the seed",
    "SOURCE.md": "what this folder is and its licence",
}
FCD_ATTRIBUTES = "id,type,x,y,angle,speed,acceleration,lane,pos,leaderID,leaderSpeed,leaderGap"


@dataclass
class SimulationResult:
    out: Path
    kind: str
    minutes: float
    seed: int
    commands: list[list[str]]
    wall_s: float

    def __str__(self) -> str:
        return (f"{self.out}: {self.kind}, {self.minutes:g} simulated minute(s), seed {self.seed}, "
                f"{self.wall_s:.1f} s wall time")




def sumo_version(bin_dir: Path) -> str:
    """First line of ``sumo --version``, e.g. 'Eclipse SUMO sumo 1.28.0'."""
    out = subprocess.run([str(bin_dir / "sumo"), "--version"], capture_output=True, text=True, check=False)
    return out.stdout.splitlines()[0].strip() if out.stdout else "unknown"


def _run(argv: list[str], bin_dir: Path, cwd: Path) -> str:
    """Run a SUMO tool in ``cwd`` and return its stderr (warnings); any error in it fails the simulation (SUMO
    reports some errors, such as an unknown output attribute, only at the end)."""
    proc = subprocess.run([str(bin_dir / argv[0]), *argv[1:]], cwd=cwd, capture_output=True, text=True,
                          check=False)
    errors = [line for line in proc.stderr.splitlines() if line.startswith("Error")]
    if proc.returncode != 0 or errors:
        tail = "\n".join((errors or proc.stderr.splitlines())[-10:])
        raise LogiqError(f"{cwd}: `{shlex.join(argv)}` failed (exit code {proc.returncode}):\n{tail}")
    return proc.stderr


# ---------------------------------------------------------------------------------------------------- networks

def _xml(path: Path, root: str, elements: list[str]) -> None:
    path.write_text(f"<{root}>\n" + "".join(f"    {e}\n" for e in elements) + f"</{root}>\n")


def _motorway(out: Path) -> list[str]:
    """3.5 km, 3 lanes, 120 km/h; an on-ramp onto a 300 m acceleration lane and a 200 m deceleration lane to an
    off-ramp (sumo.md 2a). The acceleration lane BC_0 has no successor, so ramp traffic must merge."""
    nodes = [("A", 0, 0), ("B", 1200, 0), ("C", 1500, 0), ("D", 2700, 0), ("E", 2900, 0), ("F", 3500, 0),
             ("R", 800, -60), ("X", 3300, -60)]
    main, ramp = 33.33, 22.22  # 120 and 80 km/h
    # lanes lie right of the edge line (3.2 m each): the ramps run parallel where they meet the added lane, so
    # the merge and diverge junctions stay short
    edges = [("AB", "A", "B", 3, main, 3, ""), ("BC", "B", "C", 4, main, 3, ""), ("CD", "C", "D", 3, main, 3, ""),
             ("DE", "D", "E", 4, main, 3, ""), ("EF", "E", "F", 3, main, 3, ""),
             ("RB", "R", "B", 1, ramp, 2, "800,-60 1050,-9.6 1200,-9.6"),
             ("EX", "E", "X", 1, ramp, 2, "2900,-9.6 3050,-9.6 3300,-60")]
    lanes = [("AB", 0, "BC", 1), ("AB", 1, "BC", 2), ("AB", 2, "BC", 3), ("RB", 0, "BC", 0),
             ("BC", 1, "CD", 0), ("BC", 2, "CD", 1), ("BC", 3, "CD", 2),
             ("CD", 0, "DE", 0), ("CD", 0, "DE", 1), ("CD", 1, "DE", 2), ("CD", 2, "DE", 3),
             ("DE", 0, "EX", 0), ("DE", 1, "EF", 0), ("DE", 2, "EF", 1), ("DE", 3, "EF", 2)]
    _xml(out / "network.nod.xml", "nodes", [f'<node id="{n}" x="{x}" y="{y}" type="priority"/>' for n, x, y in nodes])
    _xml(out / "network.edg.xml", "edges", [
        f'<edge id="{e}" from="{a}" to="{b}" numLanes="{n}" speed="{v}" priority="{p}"'
        + (f' shape="{shape}"/>' if shape else "/>") for e, a, b, n, v, p, shape in edges])
    _xml(out / "network.con.xml", "connections", [
        f'<connection from="{f}" to="{t}" fromLane="{fl}" toLane="{tl}"/>' for f, fl, t, tl in lanes])
    return []


_ARMS = {"N": (0, 1), "E": (1, 0), "S": (0, -1), "W": (-1, 0)}  # unit directions, clockwise
APPROACH_LANES = (2, 3, 4)
ARM_M = 300.0


BACKUP_M = 50.0  # an exit that backs up narrows to one slow lane this far from the junction


def _junction(out: Path, regime: "Regime") -> list[str]:
    """A signalised 4-way junction C: 300 m arms at ``regime.speed_kmh`` (50 km/h: sumo.md 2b), the north and
    south arms turned ``regime.skew_deg`` clockwise off the perpendicular, a fixed plan of ``regime.cycle_s``;
    with ``regime.exit_backup`` each exit narrows after ``BACKUP_M`` to one lane at ``EXIT_BACKUP_MPS``, so the
    exits back up in bursts and left-turners queue inside the junction. ``regime.approach_lanes`` sets its size:

    - 2: lane 0 right + straight, lane 1 straight + left (left-turners wait in the through lane); exits of 2;
    - 3: lane 0 right + straight, lane 1 straight, lane 2 a dedicated left; exits of 2;
    - 4: lane 0 right + straight, lanes 1-2 straight, lane 3 a dedicated left; exits of 3 (a wider junction, so
      left-turners wait farther inside it).

    Left turns get a permissive green ``g`` (they yield to oncoming traffic)."""
    approach_lanes = regime.approach_lanes
    arms = list(_ARMS)
    exits = 3 if approach_lanes == 4 else 2
    speed = regime.speed_kmh / 3.6
    nodes = ['<node id="C" x="0" y="0" type="traffic_light"/>']
    for a, (x, y) in _arm_directions(regime.skew_deg).items():
        nodes.append(f'<node id="{a}" x="{x * ARM_M:.2f}" y="{y * ARM_M:.2f}" type="priority"/>')
        if regime.exit_backup:
            nodes.append(f'<node id="{a}x" x="{x * BACKUP_M:.2f}" y="{y * BACKUP_M:.2f}" type="priority"/>')
    edges, cons = [], []
    left_lane = approach_lanes - 1
    for i, a in enumerate(arms):
        edges.append(f'<edge id="{a}2C" from="{a}" to="C" numLanes="{approach_lanes}" speed="{speed:.2f}"/>')
        if regime.exit_backup:
            edges.append(f'<edge id="C2{a}" from="C" to="{a}x" numLanes="{exits}" speed="{speed:.2f}"/>')
            edges.append(f'<edge id="{a}x2{a}" from="{a}x" to="{a}" numLanes="1" speed="{EXIT_BACKUP_MPS:g}"/>')
        else:
            edges.append(f'<edge id="C2{a}" from="C" to="{a}" numLanes="{exits}" speed="{speed:.2f}"/>')
        # arriving from arm a (clockwise order N, E, S, W): right is the next arm anticlockwise
        straight, right, left = arms[(i + 2) % 4], arms[(i + 3) % 4], arms[(i + 1) % 4]
        cons += [(a, 0, right, 0), (a, 0, straight, 0)]
        cons += [(a, k, straight, min(k, exits - 1)) for k in range(1, approach_lanes - (approach_lanes > 2))]
        cons += [(a, left_lane, left, exits - 1)]
    _xml(out / "network.nod.xml", "nodes", nodes)
    _xml(out / "network.edg.xml", "edges", edges)
    _xml(out / "network.con.xml", "connections", [
        f'<connection from="{a}2C" to="C2{b}" fromLane="{fl}" toLane="{tl}"/>' for a, fl, b, tl in cons])
    return ["--tls.layout", "opposites", "--tls.left-green.time", "0", "--tls.cycle.time", f"{regime.cycle_s:g}"]


EXIT_BACKUP_MPS = 2.5  # the slow lane of an exit that backs up: about 800 veh/h at SUMO's default gaps


def _arm_directions(skew_deg: float) -> dict[str, tuple[float, float]]:
    """Unit directions of the arms: east and west as ``_ARMS``, north and south turned ``skew_deg`` clockwise."""
    a = math.radians(skew_deg)
    return {"N": (math.sin(a), math.cos(a)), "E": (1.0, 0.0), "S": (-math.sin(a), -math.cos(a)), "W": (-1.0, 0.0)}


def _exit_edge(regime: "Regime", arm: str) -> str:
    """The last edge of the exit towards ``arm`` (where a route ends)."""
    return f"{arm}x2{arm}" if regime.exit_backup else f"C2{arm}"


# ------------------------------------------------------------------------------------------------------ demand

def _flow(fid: str, vtype: str, src: str, dst: str, veh_per_h: float, end_s: float) -> str:
    # probability per second (SUMO scales it to the step): random arrivals, reproducible with --seed
    return (f'<flow id="{fid}" type="{vtype}" begin="0" end="{end_s:g}" probability="{veh_per_h / 3600:.4f}" '
            f'from="{src}" to="{dst}" departLane="best" departSpeed="max"/>')


@dataclass(frozen=True)
class Regime:
    """What makes a simulated drive realistic (docs/sumo.md, "Regimes").

    lane_change_duration_s: SUMO's ``--lanechange.duration``: a lane change moves the vehicle sideways over this
        many seconds (real ones take 2-6 s); 0 = SUMO's instantaneous change.
    truck_share, bus_share: shares of the motor vehicles that are trucks (vClass truck) and buses (vClass bus).
    approach_lanes: lanes of each junction approach (2, 3 or 4); the junction only.
    demand: a factor on every flow (1 = the volumes of docs/sumo.md).
    creep: left-turners stop at the line and creep into the junction (below 3 m/s) to their waiting position.
    motorcycle_share: share of the motor vehicles that are motorcycles (vClass motorcycle); the junction only.
    skew_deg: the junction's north and south arms turned this far (0-45 degrees) off the perpendicular.
    cycle_s: the junction's signal cycle in seconds (30-180).
    speed_kmh: the junction arms' speed limit (20-80 km/h).
    exit_backup: the junction's exits narrow to one slow lane 50 m on, so they back up into the junction.
    """

    lane_change_duration_s: float = 3.0
    truck_share: float = 0.15
    bus_share: float = 0.05
    approach_lanes: int = 3
    demand: float = 1.0
    creep: bool = True
    motorcycle_share: float = 0.0
    skew_deg: float = 0.0
    cycle_s: float = 90.0
    speed_kmh: float = 50.0
    exit_backup: bool = False

    def __post_init__(self) -> None:
        if not self.lane_change_duration_s >= 0:
            raise LogiqError(f"--lane-change-duration {self.lane_change_duration_s}: give seconds >= 0 (0 = SUMO's "
                             "instantaneous lane change).")
        if not (0 <= self.truck_share and 0 <= self.bus_share and 0 <= self.motorcycle_share
                and self.truck_share + self.bus_share + self.motorcycle_share <= 0.9):
            raise LogiqError(f"--truck-share {self.truck_share:g}, --bus-share {self.bus_share:g} and "
                             f"--motorcycle-share {self.motorcycle_share:g}: give shares >= 0 whose sum is at most "
                             "0.9 (the rest are cars).")
        if not 0 <= self.skew_deg <= 45:
            raise LogiqError(f"--skew {self.skew_deg:g}: give degrees in [0, 45] off the perpendicular.")
        if not 30 <= self.cycle_s <= 180:
            raise LogiqError(f"--cycle {self.cycle_s:g}: give a signal cycle in [30, 180] seconds.")
        if not 20 <= self.speed_kmh <= 80:
            raise LogiqError(f"--speed {self.speed_kmh:g}: give the junction's speed limit in [20, 80] km/h.")
        if self.approach_lanes not in APPROACH_LANES:
            raise LogiqError(f"--approach-lanes {self.approach_lanes}: choose one of "
                             f"{', '.join(map(str, APPROACH_LANES))}.")
        if not self.demand > 0:
            raise LogiqError(f"--demand {self.demand}: give a positive factor on the traffic volumes.")

    def describe(self) -> str:
        change = (f"{self.lane_change_duration_s:g} s lane changes" if self.lane_change_duration_s
                  else "instantaneous lane changes")
        text = (f"{change}, {self.truck_share * 100:g} % trucks, {self.bus_share * 100:g} % buses, demand x"
                f"{self.demand:g}")
        if self.motorcycle_share:
            text += f", {self.motorcycle_share * 100:g} % motorcycles"
        return text


def _flow(fid: str, vtype: str, src: str, dst: str, veh_per_h: float, end_s: float) -> str:
    # probability per second (SUMO scales it to the step): random arrivals, reproducible with --seed
    return (f'<flow id="{fid}" type="{vtype}" begin="0" end="{end_s:g}" probability="{veh_per_h / 3600:.4f}" '
            f'from="{src}" to="{dst}" departLane="best" departSpeed="max"/>')


def _vehicle_mix(regime: Regime, name: str, cars: list[tuple[str, str, float]], truck: str, bus: str,
                 suffix: str = "", motorcycle: str = "") -> list[str]:
    """A vTypeDistribution ``name``: the car types share 1 - trucks - buses (- motorcycles, where ``motorcycle``
    is given) in their given proportions."""
    moto_share = regime.motorcycle_share if motorcycle else 0.0
    car_share = 1.0 - regime.truck_share - regime.bus_share - moto_share
    total = sum(p for _, _, p in cars)
    members = [f'    <vType id="{tid}" {attrs} probability="{car_share * p / total:.4f}"/>' for tid, attrs, p in cars]
    if regime.truck_share:
        members.append(f'    <vType id="truck{suffix}" {truck} probability="{regime.truck_share:.4f}"/>')
    if regime.bus_share:
        members.append(f'    <vType id="bus{suffix}" {bus} probability="{regime.bus_share:.4f}"/>')
    if moto_share:
        members.append(f'    <vType id="motorcycle{suffix}" {motorcycle} probability="{moto_share:.4f}"/>')
    return [f'<vTypeDistribution id="{name}">', *members, "</vTypeDistribution>"]


def _motorway_routes(end_s: float, regime: Regime) -> list[str]:
    """About 4760 veh/h from a mix of normal cars, aggressive cars, trucks and coaches: dense, with many lane
    changes (with SUMO's default drivers alone there are hardly any conflicts, sumo.md 2a)."""
    types = _vehicle_mix(
        regime, "mix",
        [("car", 'vClass="passenger" length="4.6" width="1.8" speedFactor="normc(1,0.1,0.8,1.2)"', 0.70),
         ("aggressive", 'vClass="passenger" length="4.5" width="1.8" tau="0.5" minGap="1" lcAssertive="4" '
                        'lcSpeedGain="2" speedFactor="normc(1.1,0.1,0.9,1.3)"', 0.30)],
        'vClass="truck" length="16.5" width="2.55" maxSpeed="25" speedFactor="normc(1,0.05,0.9,1.1)"',
        'vClass="bus" length="13.5" width="2.55" maxSpeed="27.8" speedFactor="normc(1,0.05,0.9,1.1)"')
    flows = [("main_through", "AB", "EF", 3600), ("main_exit", "AB", "EX", 500),
             ("ramp_through", "RB", "EF", 600), ("ramp_exit", "RB", "EX", 60)]
    return types + [_flow(f, "mix", a, b, q * regime.demand, end_s) for f, a, b, q in flows]


# creeping left-turners: a car queued at the line accelerates gently (1 m/s^2) towards its waiting position inside
# the junction a few metres ahead, so it rolls there at 1-3 m/s instead of SUMO's brisk 2.6 m/s^2 start
CREEP = 'accel="1.0"'


def _junction_routes(end_s: float, regime: Regime) -> list[str]:
    """1800 cars/h and 300 bicycles/h over the 12 turning movements (times ``demand``); bicycles share every lane
    with cars; trucks and buses take their shares of the motor vehicles."""
    car = 'vClass="passenger" length="4.6" width="1.8" speedFactor="normc(1,0.1,0.8,1.2)"'
    truck = 'vClass="truck" length="12" width="2.5" maxSpeed="22" speedFactor="normc(1,0.05,0.9,1.1)"'
    bus = 'vClass="bus" length="12" width="2.55" maxSpeed="22" speedFactor="normc(1,0.05,0.9,1.1)"'
    moto = 'vClass="motorcycle" length="2.2" width="0.9" speedFactor="normc(1,0.1,0.8,1.2)"'
    types = _vehicle_mix(regime, "mix", [("car", car, 1.0)], truck, bus, motorcycle=moto)
    # left-turners of their own types: with ``creep`` they start gently from the line
    slow = f" {CREEP}" if regime.creep else ""
    types += _vehicle_mix(regime, "left_mix", [("left_car", car + slow, 1.0)], truck + slow, bus + slow,
                          suffix="_left", motorcycle=moto + slow)
    types.append('<vType id="bike" vClass="bicycle" length="1.6" width="0.65" maxSpeed="6" '
                 'speedFactor="normc(1,0.1,0.7,1.3)"/>')
    arms = list(_ARMS)
    flows = []
    for i, a in enumerate(arms):
        for turn, b, cars, bikes in (("straight", arms[(i + 2) % 4], 250, 45), ("left", arms[(i + 1) % 4], 100, 15),
                                     ("right", arms[(i + 3) % 4], 100, 15)):
            mix = "left_mix" if turn == "left" else "mix"
            to = _exit_edge(regime, b)
            flows.append(_flow(f"car_{a}_{turn}", mix, f"{a}2C", to, cars * regime.demand, end_s))
            flows.append(_flow(f"bike_{a}_{turn}", "bike", f"{a}2C", to, bikes * regime.demand, end_s))
    return types + flows


# ---------------------------------------------------------------------------------------------------------- run

def simulate(kind: str, minutes: float, seed: int, out: str | Path, regime: Regime | None = None,
             noise: Noise | None = None, perceived: str | Path | None = None) -> SimulationResult:
    """Build the ``kind`` network, run ``minutes`` of traffic with ``seed`` in ``regime`` (default: ``Regime()``)
    and write ``OUTPUTS`` into ``out``. With ``perceived``, also write a perceived copy of the run (the same
    drive with ``noise``, ``perceive.perceive``) into that folder."""
    regime = regime or Regime()
    if perceived is not None and noise is None:
        noise = Noise(seed=seed)
    if kind not in KINDS:
        raise LogiqError(f"unknown simulation '{kind}'; choose one of {', '.join(KINDS)}.")
    if not minutes > 0:
        raise LogiqError(f"--minutes {minutes}: give a positive number of simulated minutes.")
    bin_dir = sumo_bin()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    end_s = round(minutes * 60, 1)
    net_options = _motorway(out) if kind == "motorway" else _junction(out, regime)
    routes = _motorway_routes(end_s, regime) if kind == "motorway" else _junction_routes(end_s, regime)
    _xml(out / "routes.rou.xml", "routes", routes)
    netconvert = ["netconvert", "--node-files", "network.nod.xml", "--edge-files", "network.edg.xml",
                  "--connection-files", "network.con.xml", "--no-turnarounds", *net_options,
                  "--output-file", "network.net.xml.gz"]
    run = ["sumo", "--net-file", "network.net.xml.gz", "--route-files", "routes.rou.xml"]
    if kind == "junction":
        # dest is relative to the additional file's folder (sumo.md 3): both live in ``out``
        _xml(out / "tls.add.xml", "additional",
             ['<timedEvent type="SaveTLSStates" source="C" dest="tls_states.xml.gz"/>'])
        run += ["--additional-files", "tls.add.xml"]
    run += [
        "--begin", "0", "--end", f"{end_s:g}", "--step-length", f"{STEP_S:g}", "--seed", str(seed),
        "--no-step-log", "--lanechange.duration", f"{regime.lane_change_duration_s:g}",
        "--fcd-output", "fcd.xml.gz", "--fcd-output.attributes", FCD_ATTRIBUTES,
        "--fcd-output.max-leader-distance", "250",
        "--lanechange-output", "lanechange.xml.gz", "--lanechange-output.xy",
        "--device.ssm.probability", "1", "--device.ssm.deterministic", "--device.ssm.measures", "TTC DRAC PET",
        "--device.ssm.thresholds", SSM_THRESHOLDS, "--device.ssm.range", "50", "--device.ssm.extratime", "5",
        "--device.ssm.file", "ssm.xml.gz", "--device.ssm.write-positions",
        "--collision.action", "warn", "--collision.check-junctions", "--collision-output", "collisions.xml.gz",
        "--tripinfo-output", "tripinfo.xml.gz",
    ]
    commands = [netconvert, run]
    (out / "sumo.log").write_text("".join(_run(argv, bin_dir, out) for argv in commands))
    version = sumo_version(bin_dir)
    options = command_options(kind, minutes, seed, regime)
    (out / "cmd.txt").write_text(
        f"# logiq-sql simulate {options}\n"
        f"# {version}; binaries from the eclipse-sumo package (sumo.SUMO_HOME/bin); run in this folder\n"
        f"# seed {seed}\n" + "".join(shlex.join(c) + "\n" for c in commands))
    (out / "SOURCE.md").write_text(_source_md(kind, options, minutes, seed, version, regime))
    if perceived is not None:
        perceive(out, perceived, noise)
    return SimulationResult(out, kind, minutes, seed, commands, time.perf_counter() - started)


def command_options(kind: str, minutes: float, seed: int, regime: Regime) -> str:
    """The simulate command line of this run (every regime option spelt out)."""
    text = (f"{kind} --minutes {minutes:g} --seed {seed} --lane-change-duration {regime.lane_change_duration_s:g} "
            f"--truck-share {regime.truck_share:g} --bus-share {regime.bus_share:g} --demand {regime.demand:g}")
    if kind == "junction":
        text += f" --approach-lanes {regime.approach_lanes}" + ("" if regime.creep else " --no-creep")
        # the options added for issue 36, spelt out only where they differ from the default (older runs' command
        # lines stay as they were)
        default = Regime()
        for flag, value, was in (("--motorcycle-share", regime.motorcycle_share, default.motorcycle_share),
                                 ("--skew", regime.skew_deg, default.skew_deg),
                                 ("--cycle", regime.cycle_s, default.cycle_s),
                                 ("--speed", regime.speed_kmh, default.speed_kmh)):
            if value != was:
                text += f" {flag} {value:g}"
        if regime.exit_backup:
            text += " --exit-backup"
    return text


def _source_md(kind: str, options: str, minutes: float, seed: int, version: str, regime: Regime) -> str:
    what = {
        "motorway": "a 3.5 km, 3-lane motorway at 120 km/h with an on-ramp (300 m acceleration lane) and an "
                    "off-ramp (200 m deceleration lane); about 4760 veh/h (times the demand factor) of normal and "
                    "aggressive cars (tau 0.5 s, minGap 1 m, lcAssertive 4), trucks (16.5 m) and coaches (13.5 m)",
        "junction": f"a signalised 4-way junction, 300 m arms at {regime.speed_kmh:g} km/h"
                    + (f", the north and south arms {regime.skew_deg:g} degrees off the perpendicular"
                       if regime.skew_deg else "")
                    + f", approaches of {regime.approach_lanes} lanes, a {regime.cycle_s:g} s two-phase plan where "
                    "left turns get a permissive green `g` and yield to oncoming traffic"
                    + (f"; every exit narrows to one lane at {EXIT_BACKUP_MPS:g} m/s {BACKUP_M:g} m on, so it "
                       "backs up into the junction" if regime.exit_backup else "")
                    + "; 1800 motor vehicles/h and 300 bicycles/h (times the demand factor) sharing the lanes"
                    + ("; left-turners start gently from the line and creep to their waiting position"
                       if regime.creep else ""),
    }[kind]
    files = "\n".join(f"| `{name}` | {doc} |" for name, doc in OUTPUTS.items()
                      if kind == "junction" or name != "tls_states.xml.gz")
    return f"""# SUMO simulation: {kind}, seed {seed}

Generated by `logiq-sql simulate {options}` with {version}: {what}; {regime.describe()}.
{minutes:g} simulated minute(s) at {STEP_S:g} s steps; the exact commands are in `cmd.txt`. The same command
gives the same trajectories (only the date in SUMO's header comments differs).

Vehicles enter from t = 0 s: the first {WARMUP_S} s are warm-up while the network fills (the tracks still include
them; leave them out of statistics).

| file | content |
|---|---|
{files}

Ingest with `logiq-sql ingest sumo <this folder> --db FILE`: only the network, the vehicle types, the FCD positions
and the signal states are read; lane changes, SSM conflicts, trip info, collisions and the FCD lane/leader columns
are SUMO's answers, kept for evaluation only (docs/sumo.md).

Licence: generated data, no third-party data and no third-party licence. Made with Eclipse SUMO (EPL-2.0,
https://eclipse.dev/sumo).
"""
