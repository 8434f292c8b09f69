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

import shlex
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from logiq_sql.errors import LogiqError

KINDS = ("motorway", "junction")
STEP_S = 0.1
# SSM logs an encounter when TTC < 5 s, DRAC > 3 m/s^2 or PET < 2 s. 5 s rather than SUMO's 3 s: with
# collision-free Krauss drivers few encounters go below 3 s, and the TTC cross-check needs car-following pairs.
SSM_THRESHOLDS = "5.0 3.0 2.0"
WARMUP_S = 60
SUMO_VERSION = "1.28.0"  # the pinned eclipse-sumo of the [sumo] extra
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


# ----------------------------------------------------------------------------------------------- SUMO binaries

def sumo_bin() -> Path:
    """The folder of SUMO's binaries, from the ``sumo`` package of the [sumo] extra."""
    try:
        import sumo
    except ImportError:
        raise LogiqError(
            "Eclipse SUMO is not installed. Fix: pip install 'logiq-sql[sumo]' (eclipse-sumo and sumolib "
            f"{SUMO_VERSION}, about 280 MB), then run the command again."
        ) from None
    folder = Path(sumo.SUMO_HOME) / "bin"
    if not (folder / "sumo").is_file():
        raise LogiqError(f"{folder}: the sumo package has no sumo binary here. Fix: pip install --force-reinstall "
                         f"'logiq-sql[sumo]'.")
    return folder


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


_ARMS = {"N": (0, 300), "E": (300, 0), "S": (0, -300), "W": (-300, 0)}  # clockwise


def _junction(out: Path) -> list[str]:
    """A signalised 4-way junction C: 300 m arms at 50 km/h; approaches of 3 lanes (0: right + straight,
    1: straight, 2: dedicated left), exits of 2 (sumo.md 2b). Left turns get a permissive green ``g``."""
    arms = list(_ARMS)
    nodes = ['<node id="C" x="0" y="0" type="traffic_light"/>'] + [
        f'<node id="{a}" x="{x}" y="{y}" type="priority"/>' for a, (x, y) in _ARMS.items()]
    edges, cons = [], []
    for i, a in enumerate(arms):
        edges.append(f'<edge id="{a}2C" from="{a}" to="C" numLanes="3" speed="13.89"/>')
        edges.append(f'<edge id="C2{a}" from="C" to="{a}" numLanes="2" speed="13.89"/>')
        # arriving from arm a (clockwise order N, E, S, W): right is the next arm anticlockwise
        straight, right, left = arms[(i + 2) % 4], arms[(i + 3) % 4], arms[(i + 1) % 4]
        cons += [(a, 0, right, 0), (a, 0, straight, 0), (a, 1, straight, 1), (a, 2, left, 1)]
    _xml(out / "network.nod.xml", "nodes", nodes)
    _xml(out / "network.edg.xml", "edges", edges)
    _xml(out / "network.con.xml", "connections", [
        f'<connection from="{a}2C" to="C2{b}" fromLane="{fl}" toLane="{tl}"/>' for a, fl, b, tl in cons])
    return ["--tls.layout", "opposites", "--tls.left-green.time", "0", "--tls.cycle.time", "90"]


# ------------------------------------------------------------------------------------------------------ demand

def _flow(fid: str, vtype: str, src: str, dst: str, veh_per_h: float, end_s: float) -> str:
    # probability per second (SUMO scales it to the step): random arrivals, reproducible with --seed
    return (f'<flow id="{fid}" type="{vtype}" begin="0" end="{end_s:g}" probability="{veh_per_h / 3600:.4f}" '
            f'from="{src}" to="{dst}" departLane="best" departSpeed="max"/>')


def _motorway_routes(end_s: float) -> list[str]:
    """About 4760 veh/h from a mix of normal cars, aggressive cars and trucks: dense, with many lane changes
    (with SUMO's default drivers alone there are hardly any conflicts, sumo.md 2a)."""
    types = [
        '<vTypeDistribution id="mix">',
        ('    <vType id="car" vClass="passenger" length="4.6" width="1.8" speedFactor="normc(1,0.1,0.8,1.2)" '
         'probability="0.60"/>'),
        ('    <vType id="aggressive" vClass="passenger" length="4.5" width="1.8" tau="0.5" minGap="1" '
         'lcAssertive="4" lcSpeedGain="2" speedFactor="normc(1.1,0.1,0.9,1.3)" probability="0.25"/>'),
        ('    <vType id="truck" vClass="truck" length="16.5" width="2.55" maxSpeed="25" '
         'speedFactor="normc(1,0.05,0.9,1.1)" probability="0.15"/>'),
        "</vTypeDistribution>",
    ]
    flows = [("main_through", "AB", "EF", 3600), ("main_exit", "AB", "EX", 500),
             ("ramp_through", "RB", "EF", 600), ("ramp_exit", "RB", "EX", 60)]
    return types + [_flow(f, "mix", a, b, q, end_s) for f, a, b, q in flows]


def _junction_routes(end_s: float) -> list[str]:
    """1800 cars/h and 300 bicycles/h over the 12 turning movements; bicycles share every lane with cars."""
    types = [
        '<vType id="car" vClass="passenger" length="4.6" width="1.8" speedFactor="normc(1,0.1,0.8,1.2)"/>',
        ('<vType id="bike" vClass="bicycle" length="1.6" width="0.65" maxSpeed="6" '
         'speedFactor="normc(1,0.1,0.7,1.3)"/>'),
    ]
    arms = list(_ARMS)
    flows = []
    for i, a in enumerate(arms):
        for turn, b, cars, bikes in (("straight", arms[(i + 2) % 4], 250, 45), ("left", arms[(i + 1) % 4], 100, 15),
                                     ("right", arms[(i + 3) % 4], 100, 15)):
            flows.append(_flow(f"car_{a}_{turn}", "car", f"{a}2C", f"C2{b}", cars, end_s))
            flows.append(_flow(f"bike_{a}_{turn}", "bike", f"{a}2C", f"C2{b}", bikes, end_s))
    return types + flows


# ---------------------------------------------------------------------------------------------------------- run

def simulate(kind: str, minutes: float, seed: int, out: str | Path) -> SimulationResult:
    """Build the ``kind`` network, run ``minutes`` of traffic with ``seed`` and write ``OUTPUTS`` into ``out``."""
    if kind not in KINDS:
        raise LogiqError(f"unknown simulation '{kind}'; choose one of {', '.join(KINDS)}.")
    if not minutes > 0:
        raise LogiqError(f"--minutes {minutes}: give a positive number of simulated minutes.")
    bin_dir = sumo_bin()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    end_s = round(minutes * 60, 1)
    net_options = _motorway(out) if kind == "motorway" else _junction(out)
    routes = _motorway_routes(end_s) if kind == "motorway" else _junction_routes(end_s)
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
        "--no-step-log",
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
    (out / "cmd.txt").write_text(
        f"# logiq-sql simulate {kind} --minutes {minutes:g} --seed {seed}\n"
        f"# {version}; binaries from the eclipse-sumo package (sumo.SUMO_HOME/bin); run in this folder\n"
        f"# seed {seed}\n" + "".join(shlex.join(c) + "\n" for c in commands))
    (out / "SOURCE.md").write_text(_source_md(kind, minutes, seed, version))
    return SimulationResult(out, kind, minutes, seed, commands, time.perf_counter() - started)


def _source_md(kind: str, minutes: float, seed: int, version: str) -> str:
    what = {
        "motorway": "a 3.5 km, 3-lane motorway at 120 km/h with an on-ramp (300 m acceleration lane) and an "
                    "off-ramp (200 m deceleration lane); about 4760 veh/h of normal cars (60 %), aggressive cars "
                    "(25 %: tau 0.5 s, minGap 1 m, lcAssertive 4) and trucks (15 %, 16.5 m)",
        "junction": "a signalised 4-way junction, 300 m arms at 50 km/h, approaches of 3 lanes (right + straight, "
                    "straight, dedicated left), a 90 s two-phase plan where left turns get a permissive green `g` "
                    "and yield to oncoming traffic; 1800 cars/h and 300 bicycles/h sharing the lanes",
    }[kind]
    files = "\n".join(f"| `{name}` | {doc} |" for name, doc in OUTPUTS.items()
                      if kind == "junction" or name != "tls_states.xml.gz")
    return f"""# SUMO simulation: {kind}, seed {seed}

Generated by `logiq-sql simulate {kind} --minutes {minutes:g} --seed {seed}` with {version}: {what}.
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
