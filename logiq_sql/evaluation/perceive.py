"""A perceived copy of a SUMO run: the same drive as a perception stack would report it.

Why: real logs come from perception stacks, whose tracks jitter and miss detections; SUMO's are exact. The
matcher should be measured on tracks that look like a perception stack's while the labeller keeps reading SUMO's
own records. So the noise goes into a *copy*: ``perceive(run, out)`` writes a run folder of the same name under
``out`` holding the network, the vehicle types, the signal states and a perturbed FCD (``fcd.parquet``, SUMO's
native Parquet columns, which ``ingest sumo`` reads), and none of SUMO's answers (lane, leader, lane changes,
SSM). The original run is never touched; ``label sumo`` reads it, ``ingest sumo`` the copy.

Noise, per FCD row (one detection of one road user at one step), drawn with ``numpy.random.default_rng(seed)``
in the FCD's row order, so the same run, levels and seed give the same copy:

- position: the front bumper's x and y each + N(0, position_m);
- heading: SUMO's angle + N(0, heading_deg);
- speed: + N(0, speed_mps), clipped at 0 (a tracker reports a speed magnitude);
- dropped: each detection is left out with probability ``drop_share`` (a missed detection: a gap of one or
  more steps in that road user's track).

Acceleration is left as SUMO wrote it (the issue's noise model has none). docs/evaluation.md.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import polars as pl

from logiq_sql.core.errors import InputError
from logiq_sql.ingestion.readers.sumo import read_fcd, run_file

# the FCD columns a reader of tracks uses, under SUMO's native Parquet names
_NATIVE = {"t_s": "timestep_time", "vehicle_id": "vehicle_id", "type_id": "vehicle_type", "x_m": "vehicle_x",
           "y_m": "vehicle_y", "angle_deg": "vehicle_angle", "speed_mps": "vehicle_speed",
           "accel_mps2": "vehicle_acceleration"}
# copied unchanged: what ingest reads besides the FCD
_COPIED = ("*.net.xml", "*.net.xml.gz", "*.rou.xml", "*.rou.xml.gz", "tls_states*.xml", "tls_states*.xml.gz")


@dataclass(frozen=True)
class Noise:
    """Perception-like noise levels (standard deviations; drop_share a probability in [0, 1))."""

    position_m: float = 0.0
    heading_deg: float = 0.0
    speed_mps: float = 0.0
    drop_share: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("position_m", "heading_deg", "speed_mps"):
            if not getattr(self, name) >= 0:
                raise InputError(f"noise {name} = {getattr(self, name)}: give a standard deviation >= 0.")
        if not 0 <= self.drop_share < 1:
            raise InputError(f"noise drop_share = {self.drop_share}: give a share of dropped detections in [0, 1), "
                             "e.g. 0.02 for 2 %.")

    def __str__(self) -> str:
        return (f"position {self.position_m:g} m, heading {self.heading_deg:g} deg, speed {self.speed_mps:g} m/s, "
                f"{self.drop_share * 100:g} % dropped, seed {self.seed}")


def perturb(fcd: pl.DataFrame, noise: Noise) -> pl.DataFrame:
    """The FCD rows with ``noise`` applied (rows in the given order; dropped rows left out)."""
    rng = np.random.default_rng(noise.seed)
    n = fcd.height
    dx, dy = rng.normal(0.0, noise.position_m, n), rng.normal(0.0, noise.position_m, n)
    dh, dv = rng.normal(0.0, noise.heading_deg, n), rng.normal(0.0, noise.speed_mps, n)
    kept = rng.random(n) >= noise.drop_share
    return (fcd.with_columns(x_m=pl.col("x_m") + dx, y_m=pl.col("y_m") + dy,
                             angle_deg=(pl.col("angle_deg") + dh) % 360.0,
                             speed_mps=(pl.col("speed_mps") + dv).clip(lower_bound=0.0))
            .filter(pl.Series(kept)))


def perceive(run: str | Path, out: str | Path, noise: Noise) -> Path:
    """Write ``out/<run's name>/``: the run's network, types and signal states and its FCD with ``noise``.

    Returns the new run folder. ``out`` must not be the run's own parent folder (the copy keeps the run's name,
    which is its drive id, so that labels of the original score the copy's matches).
    """
    run, out = Path(run), Path(out)
    if not run.is_dir():
        raise InputError(f"{run}: not a folder; pass a SUMO run folder (logiq-sql simulate writes one).")
    target = out / run.name
    if target.resolve() == run.resolve():
        raise InputError(f"--perceived {out}: the perceived copy would overwrite the run itself. Fix: give "
                         "another folder (the copy keeps the run's folder name, its drive id).")
    fcd_path = run_file(run, ("fcd*.xml", "fcd*.xml.gz", "fcd*.parquet"), "FCD",
                        "simulate the run again (logiq-sql simulate writes fcd.xml.gz).")
    fcd = read_fcd(fcd_path, tuple(_NATIVE))
    target.mkdir(parents=True, exist_ok=True)
    for old in target.glob("fcd*"):
        old.unlink()
    for pattern in _COPIED:
        for f in run.glob(pattern):
            shutil.copy2(f, target / f.name)
    noisy = perturb(fcd.select(*_NATIVE), noise)
    noisy.rename(_NATIVE).write_parquet(target / "fcd.parquet", compression="zstd")
    (target / "noise.json").write_text(json.dumps({**asdict(noise), "source": str(run.resolve()),
                                                   "rows": fcd.height, "rows_kept": noisy.height}, indent=2) + "\n")
    (target / "SOURCE.md").write_text(
        f"# Perceived copy of the SUMO run {run.name}\n\nWritten by logiq_sql.evaluation.perceive from {run}: "
        f"the network, vehicle types and signal states unchanged; `fcd.parquet` holds SUMO's FCD with "
        f"perception-like noise ({noise}; {fcd.height - noisy.height} of {fcd.height} detections dropped). "
        "SUMO's own answers (lanes, leaders, lane changes, SSM) are not here: label the original run.\n\n"
        "Licence: generated data, no third-party data and no third-party licence. Made with Eclipse SUMO "
        "(EPL-2.0, https://eclipse.dev/sumo).\n")
    return target
