"""Eclipse SUMO runs: one run folder (network, route files, FCD, signal states) is one drive.

Made by ``logiq-sql simulate`` (docs/sumo.md) or any SUMO run that wrote the same files. What is read:

Drive
    drive_id = the folder name; source_path = the folder; dt_s = the median step between FCD timesteps; no
    recorded ego (``is_ego`` False, ``ego_actor_id`` None): ``--ego auto`` then makes every car the SUT in turn.
    map_id = ``sumo-`` + the first 16 hex digits of the SHA-1 of the network file's text without its XML comments
    (netconvert's header comment holds the date and input paths), so every run on one network shares one map.

Files are found by content, never by name: a ``.sumocfg`` in the folder names the network, route, additional
    and output files (``run_files``); files it does not name are recognised by their root element (``<net>``,
    ``<routes>``, ``<additional>``, ``<fcd-export>``, ``<tlsStates>``, ...) or, for Parquet, by SUMO's FCD columns.
    Plain or gzipped, any file name (``net.xml.gz``, ``my_run.xml``) works.

Tracks, from the FCD output: XML (plain or gzipped) or SUMO's native Parquet (one per folder)
    One row per ``<vehicle>`` or ``<person>`` element per ``<timestep>``; frame = round(time / dt_s),
    t_s = the simulation time (so SUMO's own outputs line up with the tracks). SUMO's x, y are the centre of the
    *front bumper* and its angle is in navigation degrees (0 = north, clockwise): heading_rad =
    radians(90 - angle) wrapped into (-pi, pi], centre = front - length/2 * (cos, sin)(heading). speed_mps and
    accel_mps2 are the FCD speed and acceleration. length_m, width_m and the kind come from the vehicle type
    (``read_vtypes``). SUMO's lane, lane position and leader columns are simulator answers: they are not put in
    the tracks (``read_fcd`` returns them for evaluation); lanes are found from x/y and the map at ingest.
    Rows whose type no route file defines are dropped and counted in rows_rejected with the type ids.

Vehicle types, from the route and additional files (``<vType>`` anywhere, ``<vTypeDistribution>`` members included)
    length/width default per vClass to SUMO 1.28's values (``VCLASS_SIZE_M``, read from SUMO itself); a type
    without vClass is ``passenger``; SUMO's built-in ``DEFAULT_*TYPE`` ids are known without a route file.
    Kind by vClass (``KINDS``): passenger, private, taxi, evehicle, hov, vip, army, custom1/2, delivery -> vehicle;
    truck, trailer -> truck; bus, coach -> bus; motorcycle, moped -> motorcycle; bicycle, scooter -> cyclist;
    pedestrian, wheelchair -> person; emergency, authority -> emergency_vehicle; rail, tram, ship, aircraft,
    drone, container and cable car classes (no LogIQ kind fits) -> object.

Map, from the network (exactly one per folder)
    lanes: every lane of every edge, ``internal`` (junction) lanes included. Centre line = the lane ``shape``;
    polygon = the centre line buffered by width/2 with flat ends (width 3.2 m, SUMO's default, when absent);
    lane_type = the edge function (``normal``, ``internal``, ``crossing``, ``walkingarea``); speed_limit_mps =
    the lane ``speed``; junction_id = the junction of an internal lane (``:J_3_0`` lies in ``J``). Neighbours:
    the lane with index + 1 on the same edge is the left one, index - 1 the right one (same direction); where a
    leftmost lane has ``<neigh lane>`` (an opposite-direction lane), that is its left neighbour, not same direction.
    lane_successors: from every ``<connection>``, internal ones included: from lane -> ``via`` (the internal lane),
    or -> the to lane when there is no via; the internal -> internal and internal -> normal steps are connections
    of their own. turn from ``dir``: s -> straight, l and L (partly left) -> left, r and R -> right, t (U-turn) ->
    NULL.
    junctions: every junction except ``internal`` and ``dead_end`` ones, polygon = its ``shape``.
    traffic_lights: one light per controlled link: light_id = ``{tls id}:{link index}``; one row for the incoming
    lane and one for the internal (via) lane the link leads onto; direction = the link's turn (as above, ``t`` ->
    u_turn); x/y = the stop line (end of the incoming lane's centre line).

Traffic-light states, from the ``<tlsStates>`` file (``SaveTLSStates``: ``<tlsState time id state>``)
    Character i of ``state`` is link i: one row per light (``{tls id}:{i}``) and frame, from its first record to
    the last track frame, the last record carried forward. G and g -> green (``g`` is a *permissive* green: the
    movement must yield, e.g. a left turn to oncoming traffic), y -> yellow, r -> red, u -> red_yellow,
    o and O -> off, s (stop, then go: a stop sign on a signal) -> red, anything else -> unknown.

Not read: lane changes, SSM, trip info, collisions (SUMO's answers, for evaluation only).
"""

from __future__ import annotations

import gzip
import hashlib
import io
import re
import xml.etree.ElementTree as ET
import zlib
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import polars as pl
import shapely

from logiq_sql.core import schema
from logiq_sql.core.errors import InputError, LogiqError
from logiq_sql.ingestion.readers.base import DriveData

SUMO_VERSION = "1.28.0"  # the pinned eclipse-sumo of the [sumo] extra


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

ATTRIBUTION = "Simulated with Eclipse SUMO (EPL-2.0); generated data, no third-party licence; see SOURCE.md"

KINDS = {
    **dict.fromkeys(("passenger", "private", "taxi", "evehicle", "hov", "vip", "army", "custom1", "custom2",
                     "delivery"), "vehicle"),
    "truck": "truck", "trailer": "truck", "bus": "bus", "coach": "bus", "motorcycle": "motorcycle",
    "moped": "motorcycle", "bicycle": "cyclist", "scooter": "cyclist", "pedestrian": "person",
    "wheelchair": "person", "emergency": "emergency_vehicle", "authority": "emergency_vehicle",
}
# SUMO 1.28's default (length, width) per vClass, as reported by the simulator for a vType with only a vClass
VCLASS_SIZE_M = {
    **dict.fromkeys(("passenger", "private", "taxi", "evehicle", "hov", "vip", "army", "authority", "custom1",
                     "custom2", "cable_car"), (5.0, 1.8)),
    "delivery": (6.5, 2.16), "emergency": (6.5, 2.16), "truck": (7.1, 2.4), "trailer": (16.5, 2.55),
    "bus": (12.0, 2.5), "coach": (14.0, 2.6), "motorcycle": (2.2, 0.9), "moped": (2.1, 0.78),
    "bicycle": (1.6, 0.65), "scooter": (1.2, 0.5), "pedestrian": (0.215, 0.478), "wheelchair": (1.2, 0.72),
    "tram": (22.0, 2.4), "rail_urban": (109.5, 3.0), "subway": (109.5, 3.0), "rail": (135.0, 2.84),
    "rail_electric": (200.0, 2.95), "rail_fast": (200.0, 2.95), "ship": (17.0, 4.0),
    "container": (6.096, 2.438), "aircraft": (72.7, 79.8), "drone": (0.5, 0.5),
}
_BUILTIN_TYPES = {"DEFAULT_VEHTYPE": "passenger", "DEFAULT_BIKETYPE": "bicycle", "DEFAULT_PEDTYPE": "pedestrian",
                  "DEFAULT_TAXITYPE": "taxi", "DEFAULT_RAILTYPE": "rail", "DEFAULT_CONTAINERTYPE": "container"}
_TURNS = {"s": "straight", "l": "left", "L": "left", "r": "right", "R": "right"}
_SIGNALS = {"G": "green", "g": "green", "y": "yellow", "r": "red", "u": "red_yellow", "o": "off", "O": "off",
            "s": "red"}
_DEFAULT_LANE_WIDTH_M = 3.2
_WKT_DIGITS = 4
_COMMENT = re.compile(rb"<!--.*?-->", re.DOTALL)
CHUNK_BYTES = 16 << 20  # decompressed XML parsed at a time: memory stays bounded on files of any size

# read_fcd columns: name, FCD attribute, native Parquet column, dtype
_FCD = (
    ("vehicle_id", "id", "vehicle_id", pl.String), ("type_id", "type", "vehicle_type", pl.String),
    ("x_m", "x", "vehicle_x", pl.Float64), ("y_m", "y", "vehicle_y", pl.Float64),
    ("angle_deg", "angle", "vehicle_angle", pl.Float64), ("speed_mps", "speed", "vehicle_speed", pl.Float64),
    ("accel_mps2", "acceleration", "vehicle_acceleration", pl.Float64),
    ("lane_id", "lane", "vehicle_lane", pl.String), ("lane_pos_m", "pos", "vehicle_pos", pl.Float64),
    ("leader_id", "leaderID", "vehicle_leaderID", pl.String),
    ("leader_gap_m", "leaderGap", "vehicle_leaderGap", pl.Float64),
    ("leader_speed_mps", "leaderSpeed", "vehicle_leaderSpeed", pl.Float64),
)
FCD_COLUMNS = ("t_s", *(c[0] for c in _FCD))
_TRACK_FCD_COLUMNS = ("t_s", "vehicle_id", "type_id", "x_m", "y_m", "angle_deg", "speed_mps", "accel_mps2")


# ------------------------------------------------------------------------------------------------ files

def run_folders(path: str | Path) -> list[Path]:
    """The run folders at or under ``path``: folders holding a ``.sumocfg``, a network or an FCD output, found by
    content, whatever the files are named (a file means its folder).

    A folder with none of them is returned as it is, so that reading it says what is missing.
    """
    path = Path(path)
    if path.is_file():
        return [path.parent]
    if _is_run(path):
        return [path]
    found = sorted(d for d in path.rglob("*") if d.is_dir() and _is_run(d))
    return found or [path]


# the root element of each SUMO file the reader and the labeller use -> its role in a run folder
ROLES = {"net": "network", "routes": "routes", "additional": "routes", "fcd-export": "fcd",
         "tlsStates": "tls_states", "lanechanges": "lanechange", "SSMLog": "ssm", "tripinfos": "tripinfo",
         "collisions": "collisions"}
# the options of a .sumocfg that name those files (comma- or space-separated lists)
_CONFIG_ROLES = {"net-file": "network", "route-files": "routes", "additional-files": "routes",
                 "fcd-output": "fcd", "lanechange-output": "lanechange", "tripinfo-output": "tripinfo",
                 "collision-output": "collisions"}
_SNIFF_BYTES = 1 << 16  # enough for netconvert's header comment before the root element
_ROOT_TAG = re.compile(rb"<([A-Za-z_][\w.:-]*)")
_PI = re.compile(rb"<\?.*?\?>|<!DOCTYPE[^>]*>", re.DOTALL)
_NET_FILE = re.compile(rb"<net-file[\s/>]")  # sumo's option (netconvert's configurations have sumo-net-file)


def file_role(path: Path) -> str | None:
    """What a file of a run folder is, from its content: a ``ROLES`` value, ``config`` for a SUMO configuration,
    or None (not a SUMO file, or unreadable: reading it later says why)."""
    try:
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
        if head[:2] == b"\x1f\x8b":
            head = _gunzip_head(head)
    except (OSError, zlib.error):
        return None
    if head[:4] == b"PAR1":
        try:
            names = set(pl.read_parquet_schema(path))
        except Exception:  # polars raises several types for corrupt files
            return None
        return "fcd" if names & {"timestep_time", "time"} and names & {"vehicle_x", "x"} else None
    text = _PI.sub(b"", _COMMENT.sub(b"", head))
    root = _ROOT_TAG.search(text.split(b"<!--")[0])  # a comment longer than the head hides the root: unknown
    if root is None:
        return None
    tag = root.group(1).decode(errors="replace")
    if tag in ("configuration", "sumoConfiguration") and (path.name.endswith(".sumocfg") or _NET_FILE.search(text)):
        return "config"
    return ROLES.get(tag)


def _gunzip_head(raw: bytes) -> bytes:
    """Up to ``_SNIFF_BYTES`` of the text at the start of gzip data, across gzip members (SUMO writes several);
    a truncated file still shows its root element."""
    out = b""
    while raw and len(out) < _SNIFF_BYTES:
        member = zlib.decompressobj(16 + zlib.MAX_WBITS)
        out += member.decompress(raw, _SNIFF_BYTES - len(out))
        raw = member.unused_data if member.eof else b""
    return out


def run_files(folder: Path) -> dict[str, list[Path]]:
    """The files of a run folder by role (``ROLES`` values). A ``.sumocfg`` in the folder names them first
    (net-file, route-files, additional-files, fcd-output, ...; relative to the configuration); the roles it does
    not name, or names with a file that is not there, are found by the files' root elements."""
    files = sorted(f for f in folder.iterdir() if f.is_file() and not f.name.startswith("."))
    roles = {f: file_role(f) for f in files}
    configs = [f for f, role in roles.items() if role == "config"]
    if len(configs) > 1:
        raise InputError(f"{folder}: {len(configs)} SUMO configurations ({', '.join(f.name for f in configs)}); "
                         "a run folder holds one run. Fix: move the others into folders of their own.")
    named: dict[str, list[Path]] = {}
    if configs:
        for option, role in _config_options(configs[0]):
            paths = [configs[0].parent / name for name in re.split(r"[,\s]+", option) if name]
            named.setdefault(role, []).extend(p for p in paths if p.is_file())
    found: dict[str, list[Path]] = {}
    for f, role in roles.items():
        if role and role != "config":
            found.setdefault(role, []).append(f)
    return {**found, **{role: paths for role, paths in named.items() if paths}}


def _config_options(config: Path) -> list[tuple[str, str]]:
    """(value, role) of every option of a .sumocfg that names a run file."""
    try:
        root = ET.fromstring(_read_bytes(config))
    except ET.ParseError as exc:
        raise InputError(f"{config}: not well-formed XML ({exc}). Fix: repair or remove the configuration.") from None
    return [(el.get("value", el.get("v", "")), _CONFIG_ROLES[el.tag]) for el in root.iter() if el.tag in _CONFIG_ROLES]


def _is_run(folder: Path) -> bool:
    if not folder.is_dir():
        return False
    try:
        return any(role in ("config", "network", "fcd") for role in run_files(folder))
    except InputError:  # two configurations: a run folder, whose reading reports the clash
        return True


def run_file(folder: Path, patterns: tuple[str, ...], what: str, fix: str, required: bool = True) -> Path | None:
    """The one file of a run folder matching ``patterns`` (None if absent and not required)."""
    files = sorted({f for p in patterns for f in folder.glob(p) if f.is_file()})
    if len(files) > 1:
        raise InputError(f"{folder}: {len(files)} {what} files ({', '.join(f.name for f in files)}); a run folder "
                         f"holds one. Fix: move the others into folders of their own.")
    if not files and required:
        raise InputError(f"{folder}: no {what} file ({' or '.join(patterns)}). Fix: {fix}")
    return files[0] if files else None


_FOUND_BY = {"network": "<net>", "fcd": "<fcd-export> or an FCD Parquet file", "tls_states": "<tlsStates>",
             "routes": "<routes> or <additional>", "lanechange": "<lanechanges>"}


def role_file(files: dict[str, list[Path]], folder: Path, role: str, what: str, fix: str,
              required: bool = True) -> Path | None:
    """The one file of ``role`` among a run folder's ``run_files`` (None if absent and not required)."""
    found = files.get(role, [])
    if len(found) > 1:
        raise InputError(f"{folder}: {len(found)} {what} files ({', '.join(f.name for f in found)}); a run folder "
                         f"holds one. Fix: move the others into folders of their own, or name the one to read in a "
                         f".sumocfg.")
    if not found and required:
        raise InputError(f"{folder}: no {what} file (none named by a .sumocfg, no file whose root element is "
                         f"{_FOUND_BY.get(role, role)}). Fix: {fix}")
    return found[0] if found else None


def _read_bytes(path: Path) -> bytes:
    """The whole (small) file, gunzipped when it is gzip."""
    try:
        raw = path.read_bytes()
        return gzip.decompress(raw) if raw[:2] == b"\x1f\x8b" else raw
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"{path}: not readable ({exc}). Fix: copy or regenerate the file; gzip files must be "
                         "complete.") from None


def parse_sumo_xml(path: Path, root_tags: str | tuple[str, ...], raw: bytes | None = None) -> ET.Element:
    try:
        root = ET.fromstring(_read_bytes(path) if raw is None else raw)
    except ET.ParseError as exc:
        raise InputError(f"{path}: not well-formed XML ({exc}). Fix: regenerate the file.") from None
    tags = (root_tags,) if isinstance(root_tags, str) else root_tags
    if root.tag not in tags:
        raise InputError(f"{path}: root element is <{root.tag}>, not <{'> or <'.join(tags)}>; not a SUMO "
                         f"{tags[0]} file.")
    return root


def _text_chunks(path: Path) -> Iterator[bytes]:
    """The decompressed text in pieces of about ``CHUNK_BYTES`` that end at a line end."""
    try:
        with open(path, "rb") as f:
            gzipped = f.read(2) == b"\x1f\x8b"
        rest = b""
        with (gzip.open if gzipped else open)(path, "rb") as f:
            while block := f.read(CHUNK_BYTES):
                block = rest + block
                cut = block.rfind(b"\n") + 1
                rest = block[cut:]
                if cut:
                    yield block[:cut]
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(f"{path}: cannot be read to the end ({exc}); the file is truncated or corrupt. "
                         "Fix: copy or regenerate it (SUMO must finish writing it).") from None
    if rest.strip():
        yield rest


def _prefetched(chunks: Iterator[bytes]) -> Iterator[bytes]:
    """The same chunks, the next one decompressed on a thread while the caller parses this one (zlib releases
    the GIL): about 10 % off the time of a gzipped FCD file."""
    with ThreadPoolExecutor(1) as pool:
        future = pool.submit(next, chunks, None)
        while (chunk := future.result()) is not None:
            future = pool.submit(next, chunks, None)
            yield chunk


def _lines(chunk: bytes) -> pl.DataFrame:
    """One string per line, split by Polars (no line holds the unit separator byte)."""
    return pl.read_csv(io.BytesIO(chunk), has_header=False, separator="\x1f", quote_char=None,
                       new_columns=["line"], schema={"line": pl.String})


def _attr(name: str) -> pl.Expr:
    return pl.col("line").str.extract(rf'\s{name}="([^"]*)"')


def xml_records(path: Path, element: str, attrs: Iterable[str], closing: str,
                 time_tag: str | None = None) -> pl.DataFrame:
    """The attributes (strings) of every line that opens an ``element`` (a regex) in a SUMO output, plus
    ``time`` forward-filled from the enclosing ``<time_tag time>`` lines. Vectorised: no Python object per
    element; SUMO writes one element per line."""
    attrs = list(attrs)
    cols = [_attr(a).alias(a) for a in attrs] + ([pl.col("time")] if time_tag else [])
    parts: list[pl.DataFrame] = []
    last_time: str | None = None
    last_line = b""
    for chunk in _prefetched(_text_chunks(path)):
        tail = chunk.rstrip()
        last_line = tail[tail.rfind(b"\n") + 1:].strip() if tail else last_line
        lines = _lines(chunk)
        if time_tag:  # the time of the enclosing element, carried over from the previous chunk
            lines = lines.with_columns(time=pl.col("line").str.extract(rf'<{time_tag} time="([^"]*)"')
                                       .forward_fill().fill_null(pl.lit(last_time, pl.String)))
            last_time = lines["time"][-1] if lines.height else last_time
        parts.append(lines.lazy().filter(pl.col("line").str.contains(f"<(?:{element}) ")).select(cols).collect())
    if last_line != closing.encode():
        raise InputError(f"{path}: ends before {closing} (last line {last_line[:80].decode(errors='replace')!r}); "
                         "the file is truncated. Fix: let SUMO finish the run, or regenerate the file.")
    columns = [*attrs, "time"] if time_tag else attrs
    return pl.concat(parts) if parts else pl.DataFrame(schema=dict.fromkeys(columns, pl.String))


# -------------------------------------------------------------------------------------------------------- FCD

def read_fcd(path: str | Path, columns: Iterable[str] = FCD_COLUMNS) -> pl.DataFrame:
    """The raw FCD rows of a SUMO run (``FCD_COLUMNS``, SUMO's own values: x/y = front bumper, angle in
    navigation degrees; leader_id, leader_gap_m and leader_speed_mps are NULL where SUMO writes "" / -1).

    FCD XML (plain or gzipped) is parsed line by line with vectorised Polars regexes in chunks (bounded memory);
    a Parquet file (by its magic bytes, any name) is SUMO's native Parquet output (its columns prefixed
    ``timestep_`` / ``vehicle_``).
    ``columns`` picks a subset (t_s is always included): fewer columns parse faster.
    """
    path = Path(path)
    wanted = [c for c in _FCD if c[0] in set(columns)]
    with open(path, "rb") as f:
        parquet = f.read(4) == b"PAR1"
    if parquet:
        return _read_fcd_parquet(path, wanted)
    raw = xml_records(path, "vehicle|person", [fcd for _, fcd, _, _ in wanted], "</fcd-export>", "timestep")
    return _typed(raw, {fcd: name for name, fcd, _, _ in wanted}, {name: dtype for name, _, _, dtype in wanted})


def _typed(raw: pl.DataFrame, rename: dict[str, str], dtypes: dict[str, pl.DataType]) -> pl.DataFrame:
    out = raw.rename({"time": "t_s", **rename}).with_columns(
        pl.col("t_s").cast(pl.Float64, strict=False),
        *[pl.col(n).cast(d, strict=False) for n, d in dtypes.items() if d != pl.String])
    return _leaders_null(out).select("t_s", *dtypes)


def _leaders_null(fcd: pl.DataFrame) -> pl.DataFrame:
    """SUMO writes leaderID "" and leaderGap/leaderSpeed -1 when there is no leader: NULL here."""
    if "leader_id" in fcd.columns:
        fcd = fcd.with_columns(pl.when(pl.col("leader_id") != "").then(pl.col("leader_id")).alias("leader_id"))
    for col in ("leader_gap_m", "leader_speed_mps"):
        if col in fcd.columns:
            fcd = fcd.with_columns(pl.when(pl.col(col) != -1).then(pl.col(col)).alias(col))
    return fcd


def _read_fcd_parquet(path: Path, wanted: list[tuple]) -> pl.DataFrame:
    try:
        names = pl.read_parquet_schema(path)
        frame = pl.scan_parquet(path)
        select = [pl.col("timestep_time" if "timestep_time" in names else "time").cast(pl.Float64).alias("t_s")]
        for name, fcd, native, dtype in wanted:
            src = native if native in names else fcd  # --output.column-header plain drops the prefixes
            select.append(pl.col(src).cast(dtype).alias(name) if src in names else pl.lit(None, dtype).alias(name))
        return _leaders_null(frame.select(select).collect())
    except (OSError, pl.exceptions.PolarsError) as exc:
        raise InputError(f"{path}: not a readable SUMO FCD Parquet file ({type(exc).__name__}: {exc}). "
                         "Fix: regenerate it with sumo --fcd-output fcd.parquet.") from None


# ------------------------------------------------------------------------------------------------- vehicle types

def read_vtypes(folder: str | Path) -> pl.DataFrame:
    """type_id, vclass, length_m, width_m, kind of every vType of the folder's route files and SUMO's built-ins."""
    folder = Path(folder)
    rows = {tid: (vclass, *VCLASS_SIZE_M[vclass]) for tid, vclass in _BUILTIN_TYPES.items()}
    for path in run_files(folder).get("routes", []):
        root = parse_sumo_xml(path, ("routes", "additional"))
        for vt in root.iter("vType"):
            vclass = vt.get("vClass", "passenger")
            length, width = VCLASS_SIZE_M.get(vclass, VCLASS_SIZE_M["passenger"])
            try:
                rows[vt.get("id", "")] = (vclass, float(vt.get("length", length)), float(vt.get("width", width)))
            except ValueError:
                raise InputError(f"{path}: vType {vt.get('id')!r} has a non-numeric length or width.") from None
    return pl.DataFrame(
        [(tid, vclass, length, width, KINDS.get(vclass, "object")) for tid, (vclass, length, width) in rows.items()],
        schema={"type_id": pl.String, "vclass": pl.String, "length_m": pl.Float64, "width_m": pl.Float64,
                "kind": pl.String}, orient="row")


# ------------------------------------------------------------------------------------------------------- tracks

def _tracks(fcd: pl.DataFrame, vtypes: pl.DataFrame, drive_id: str, dt: float) -> tuple[pl.DataFrame, int, str | None]:
    """Canonical tracks: box centre from the front bumper, heading from the navigation angle."""
    joined = fcd.join(vtypes.select("type_id", "kind", "length_m", "width_m"), on="type_id", how="left")
    unknown = joined.filter(pl.col("kind").is_null())
    reason = None
    if unknown.height:
        types = sorted(unknown["type_id"].cast(pl.String).fill_null("(none)").unique().to_list())
        reason = (f"{unknown.height} FCD row(s) of vehicle type(s) no route file defines dropped "
                  f"({', '.join(types[:10])}); fix: keep the *.rou.xml files of the run in its folder")
        joined = joined.filter(pl.col("kind").is_not_null())
    deg = 90.0 - pl.col("angle_deg")
    heading = (deg - 360.0 * ((deg - 180.0) / 360.0).ceil()).radians()  # (-180, 180] degrees, then radians
    tracks = joined.select(
        pl.lit(drive_id).alias("drive_id"), pl.col("vehicle_id").alias("actor_id"), "kind",
        pl.lit(False).alias("is_ego"), (pl.col("t_s") / dt).round().cast(pl.Int64).alias("frame"), "t_s",
        (pl.col("x_m") - pl.col("length_m") / 2 * heading.cos()).alias("x_m"),
        (pl.col("y_m") - pl.col("length_m") / 2 * heading.sin()).alias("y_m"),
        heading.alias("heading_rad"), "speed_mps", "accel_mps2", "length_m", "width_m",
    )
    return tracks.cast(schema.TRACKS.polars_schema), unknown.height, reason


def sample_period_s(fcd: pl.DataFrame, path: Path) -> float:
    """The run's step: the median gap between FCD timesteps."""
    steps = fcd["t_s"].drop_nulls().unique().sort().diff().drop_nulls()
    steps = steps.filter(steps > 0)
    if steps.is_empty():
        raise InputError(f"{path}: fewer than two timesteps with vehicles; the sample period is unknown. "
                         "Fix: simulate longer.")
    return round(float(steps.median()), 6)


# ---------------------------------------------------------------------------------------------------------- map

def shape_coords(shape: str) -> np.ndarray:
    return np.array([p.split(",")[:2] for p in shape.split()], dtype=float).reshape(-1, 2)


def _wkt(g):
    return shapely.to_wkt(g, rounding_precision=_WKT_DIGITS)


def _net(path: Path) -> tuple[str, tuple[pl.DataFrame, ...]]:
    raw = _read_bytes(path)
    return _map_id(raw), network_tables(path, _map_id(raw), raw=raw)


def _map_id(raw: bytes) -> str:
    return "sumo-" + hashlib.sha1(_COMMENT.sub(b"", raw)).hexdigest()[:16]


def network_of(map_id: str, folder: Path) -> Path | None:
    """The network a SUMO drive's map was read from: its run folder's network, if its text still gives map_id."""
    try:
        nets = run_files(folder).get("network", []) if folder.is_dir() else []
    except InputError:
        return None
    return next((net for net in nets if _map_id(_read_bytes(net)) == map_id), None)


def network_tables(path: Path, map_id: str, raw: bytes | None = None,
                   undo_offset: bool = False) -> tuple[pl.DataFrame, ...]:
    """lanes, lane_successors, junctions, traffic_lights of a SUMO network.

    ``undo_offset``: subtract the network's ``<location netOffset>`` from every coordinate, back to the frame of
    the source netconvert converted (an OpenDRIVE map); a SUMO run's FCD is in the shifted frame, so not there.
    """
    root = parse_sumo_xml(path, "net", raw)
    location = root.find("location")
    offset = np.zeros(2)
    if undo_offset and location is not None and location.get("netOffset"):
        offset = shape_coords(location.get("netOffset"))[0]
    return _map(root, map_id, path, offset)


def _map(root: ET.Element, map_id: str, path: Path, offset: np.ndarray) -> tuple[pl.DataFrame, ...]:
    junctions = {j.get("id"): j for j in root.iter("junction") if j.get("type") != "internal"}
    lane_rows: list[dict] = []
    for edge in root.iter("edge"):
        function = edge.get("function", "normal")
        eid = edge.get("id", "")
        junction = eid[1:].rsplit("_", 1)[0] if function == "internal" else None
        lanes = {int(lane.get("index", 0)): lane for lane in edge.iter("lane")}
        for index, lane in lanes.items():
            neigh = lane.find("neigh")
            left = lanes.get(index + 1)
            right = lanes.get(index - 1)
            lane_rows.append({
                "lane_id": lane.get("id"), "lane_type": function, "shape": lane.get("shape", ""),
                "width": float(lane.get("width", _DEFAULT_LANE_WIDTH_M)),
                "left_lane_id": left.get("id") if left is not None else (
                    neigh.get("lane") if neigh is not None else None),
                "left_same_direction": True if left is not None else (False if neigh is not None else None),
                "right_lane_id": right.get("id") if right is not None else None,
                "right_same_direction": True if right is not None else None,
                "speed_limit_mps": float(lane.get("speed")) if lane.get("speed") else None,
                "junction_id": junction if junction in junctions else None,
            })
    if not lane_rows:
        raise InputError(f"{path}: the network has no lanes.")
    try:
        coords = [shape_coords(r.pop("shape")) - offset for r in lane_rows]
        lines = shapely.linestrings(np.concatenate(coords), indices=np.repeat(np.arange(len(coords)),
                                                                               [len(c) for c in coords]))
    except (ValueError, shapely.errors.GEOSException) as exc:
        raise InputError(f"{path}: a lane shape is not a list of at least two 'x,y' points ({exc}).") from None
    widths = np.array([r.pop("width") for r in lane_rows])
    polygons = shapely.buffer(lines, widths / 2, cap_style="flat")
    empty = shapely.is_empty(polygons)  # a zero-length lane: a round blob keeps it findable
    polygons[empty] = shapely.buffer(lines[empty], widths[empty] / 2)
    lanes = pl.DataFrame(lane_rows).with_columns(
        map_id=pl.lit(map_id), polygon_wkt=pl.Series(_wkt(polygons)), centerline_wkt=pl.Series(_wkt(lines)))
    end_of = dict(zip(lanes["lane_id"], shapely.get_coordinates(shapely.get_point(lines, -1)).tolist(), strict=True))

    succ_rows, light_rows = [], []
    for con in root.iter("connection"):
        src = f"{con.get('from')}_{con.get('fromLane')}"
        dst = con.get("via") or f"{con.get('to')}_{con.get('toLane')}"
        succ_rows.append((map_id, src, dst, _TURNS.get(con.get("dir", ""))))
        if con.get("tl") and con.get("linkIndex") not in (None, "-1"):
            light = f"{con.get('tl')}:{con.get('linkIndex')}"
            x, y = end_of.get(src, (None, None))
            turn = _TURNS.get(con.get("dir", ""), "u_turn" if con.get("dir") == "t" else None)
            light_rows += [(map_id, light, lane, turn, x, y) for lane in dict.fromkeys((src, con.get("via"))) if lane]

    junction_rows = []
    for jid, j in junctions.items():
        outline = shape_coords(j.get("shape", "")) - offset
        if j.get("type") == "dead_end" or len(outline) < 3:
            continue
        parts = [g for g in shapely.get_parts(shapely.make_valid(shapely.Polygon(outline)))
                 if g.geom_type == "Polygon" and not g.is_empty]
        if parts:  # the largest part of a self-touching outline
            junction_rows.append((map_id, jid, _wkt(max(parts, key=lambda g: g.area))))
    return (
        lanes.select(schema.LANES.column_names).cast(schema.LANES.polars_schema),
        pl.DataFrame(succ_rows, schema=schema.LANE_SUCCESSORS.polars_schema, orient="row").unique(maintain_order=True),
        pl.DataFrame(junction_rows, schema=schema.JUNCTIONS.polars_schema, orient="row"),
        pl.DataFrame(light_rows, schema=schema.TRAFFIC_LIGHTS.polars_schema, orient="row"),
    )


# --------------------------------------------------------------------------------------------- light states

def _light_states(path: Path | None, drive_id: str, dt: float, max_frame: int) -> pl.DataFrame:
    if path is None:
        return schema.empty(schema.TRAFFIC_LIGHT_STATES)
    recs = xml_records(path, "tlsState", ("time", "id", "state"), "</tlsStates>")
    recs = recs.select(
        pl.col("id"), (pl.col("time").cast(pl.Float64, strict=False) / dt).round().cast(pl.Int64).alias("frame"),
        pl.col("state").str.split("").alias("code"),
    ).filter(pl.col("frame").is_not_null()).unique(["id", "frame"], keep="last")
    if recs.is_empty():
        return schema.empty(schema.TRAFFIC_LIGHT_STATES)
    links = (recs.with_columns(link=pl.int_ranges(pl.col("code").list.len())).explode("code", "link")
             .select(light_id=pl.format("{}:{}", "id", "link"), frame="frame", code="code"))
    grid = (links.group_by("light_id").agg(pl.col("frame").min().alias("first"))
            .with_columns(frame=pl.int_ranges("first", pl.max_horizontal("first", pl.lit(max_frame)) + 1))
            .explode("frame").select("light_id", "frame").sort("light_id", "frame"))
    filled = (grid.join(links, on=["light_id", "frame"], how="left", maintain_order="left")
              .with_columns(pl.col("code").forward_fill().over("light_id")))
    state = pl.col("code").replace_strict(_SIGNALS, default="unknown")
    return filled.select(pl.lit(drive_id).alias("drive_id"), "light_id", "frame", state.alias("state")).cast(
        schema.TRAFFIC_LIGHT_STATES.polars_schema)


# ------------------------------------------------------------------------------------------------------ entry

def read_sumo(path: str | Path) -> Iterator[DriveData]:
    """Read a SUMO run folder (or a folder of run folders) into one drive per run."""
    for folder in run_folders(path):
        yield _read_run(folder)


def _read_run(folder: Path) -> DriveData:
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; pass a SUMO run folder (network, route files, FCD).")
    files = run_files(folder)
    net = role_file(files, folder, "network", "SUMO network",
                    "copy the network the run used (any name, e.g. network.net.xml.gz) into the folder.")
    fcd_path = role_file(files, folder, "fcd", "FCD",
                         "run sumo with --fcd-output fcd.xml.gz (logiq-sql simulate does).")
    tls_path = role_file(files, folder, "tls_states", "signal state", "", required=False)
    map_id, (lanes, successors, junctions, lights) = _net(net)
    vtypes = read_vtypes(folder)
    fcd = read_fcd(fcd_path, _TRACK_FCD_COLUMNS)
    dt = sample_period_s(fcd, fcd_path)
    drive_id = folder.name
    tracks, rejected, reason = _tracks(fcd, vtypes, drive_id, dt)
    max_frame = int(tracks["frame"].max()) if tracks.height else 0
    return DriveData(
        drive_id=drive_id, source_format="sumo", source_path=str(folder), dt_s=dt, tracks=tracks, map_id=map_id,
        lanes=lanes, lane_successors=successors, junctions=junctions, traffic_lights=lights,
        traffic_light_states=_light_states(tls_path, drive_id, dt, max_frame), ego_actor_id=None,
        rows_read=fcd.height, rows_rejected=rejected, reject_reason=reason, attribution=ATTRIBUTION,
    )
