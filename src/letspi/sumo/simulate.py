"""Run SUMO as a subprocess and read its floating-car-data (FCD) output.

The command-line simulator is used instead of TraCI/libsumo: the ``eclipse-sumo`` wheel ships
the binaries but not the Python client packages, and one FCD file written in CSV and parsed with
pyarrow is faster than per-step TraCI calls anyway.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from letspi.sumo.binaries import sumo_binary

STEP_S = 0.04  # 25 Hz, the HighD frame rate


@dataclass(frozen=True)
class SimulationResult:
    """FCD of all vehicles on the whole road plus simulator diagnostics.

    Attributes:
        fcd: columns ``time`` [s], ``id`` (SUMO id), ``x``, ``y`` (front-bumper centre, SUMO
            axes, y up) [m], ``speed`` [m/s], ``acceleration`` [m/s²]; sorted by (id, time).
        collisions: number of collisions SUMO reported.
        wall_time_s: wall time of the simulator run [s].
    """

    fcd: pd.DataFrame
    collisions: int
    wall_time_s: float


def _last_time_in_file(path: Path) -> float | None:
    """Simulation time of the last complete line of a growing FCD CSV (cheap tail read)."""
    try:
        with path.open("rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            if size < 2:
                return None
            fh.seek(max(0, size - 512))
            tail = fh.read().decode("ascii", errors="ignore").splitlines()
    except OSError:
        return None
    for line in reversed(tail[:-1]):  # the very last line may be incomplete
        head = line.split(";", 1)[0]
        try:
            return float(head)
        except ValueError:
            continue
    return None


def run_sumo(
    net_file: Path,
    route_file: Path,
    work_dir: Path,
    *,
    end_s: float,
    seed: int,
    lane_change_duration_s: float = 4.0,
    x_range_m: tuple[float, float] | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Simulate ``[0, end_s)`` at 0.04 s steps and return the FCD.

    Args:
        net_file: the ``.net.xml``.
        route_file: the route file with vTypes and vehicles.
        work_dir: directory for the FCD/log files (a temporary directory of the caller).
        end_s: simulation end time [s].
        seed: SUMO's random seed (no randomness is left with the sigmas at 0; set for safety).
        lane_change_duration_s: duration of a (non-sublane) lane change [s]; > 0 makes lane
            changes continuous instead of instantaneous jumps.
        x_range_m: keep only FCD rows with SUMO x in this range [m] (saves memory).
        progress: called with the fraction of simulated time done, in [0, 1].
    """
    fcd_file = work_dir / "fcd.csv"
    log_file = work_dir / "sumo.log"
    cmd = [
        sumo_binary("sumo"),
        "--net-file", str(net_file), "--route-files", str(route_file),
        "--begin", "0", "--end", f"{end_s:.2f}", "--step-length", f"{STEP_S}",
        "--seed", str(int(seed)),
        # Default precision (2) quantises positions to 1 cm: 3-6 m/s² of acceleration noise.
        "--precision", "6",
        "--lanechange.duration", f"{lane_change_duration_s}",
        "--time-to-teleport", "-1",
        "--collision.action", "warn", "--collision.mingap-factor", "0",
        "--fcd-output", str(fcd_file),
        "--fcd-output.attributes", "id,x,y,speed,acceleration",
        "--no-step-log", "true", "--duration-log.disable", "true",
        "--log", str(log_file),
        "--threads", "1",
    ]
    started = time.perf_counter()
    with subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) as proc:
        while proc.poll() is None:
            time.sleep(0.25)
            if progress is not None:
                t = _last_time_in_file(fcd_file)
                if t is not None:
                    progress(min(1.0, t / end_s))
        stderr = proc.stderr.read() if proc.stderr is not None else ""
    wall = time.perf_counter() - started
    log = log_file.read_text(errors="ignore") if log_file.exists() else ""
    if proc.returncode != 0:
        raise RuntimeError(f"sumo failed ({proc.returncode}): {stderr.strip()} {log[-2000:]}")
    collisions = sum(1 for line in log.splitlines() if "collision" in line.lower())
    if progress is not None:
        progress(1.0)
    return SimulationResult(fcd=read_fcd(fcd_file, x_range_m=x_range_m), collisions=collisions, wall_time_s=wall)


def read_fcd(path: Path, *, x_range_m: tuple[float, float] | None = None) -> pd.DataFrame:
    """Read a SUMO FCD CSV (``--fcd-output x.csv``) into tidy columns sorted by (id, time).

    Args:
        path: the CSV written by SUMO (';'-separated, columns ``timestep_time``, ``vehicle_*``).
        x_range_m: if given, keep only rows with ``lo <= x <= hi`` (SUMO x, metres); filtered in
            Arrow before conversion to pandas to keep memory low.
    """
    reader = pacsv.open_csv(
        path,
        read_options=pacsv.ReadOptions(block_size=16 << 20),
        parse_options=pacsv.ParseOptions(delimiter=";"),
        convert_options=pacsv.ConvertOptions(column_types={"vehicle_id": pa.string()}),
    )
    names = [c.split("_", 1)[1] if "_" in c else c for c in reader.schema.names]
    batches = []
    for batch in reader:  # streamed: the whole-road file never sits in memory at once
        batch = batch.rename_columns(names)
        # Time steps without vehicles appear as rows with an empty id / position.
        keep = pc.is_valid(batch["x"])
        if x_range_m is not None:
            keep = pc.and_(keep, pc.and_(pc.greater_equal(batch["x"], x_range_m[0]),
                                         pc.less_equal(batch["x"], x_range_m[1])))
        batches.append(batch.filter(keep).select(["time", "id", "x", "y", "speed", "acceleration"]))
    table = pa.Table.from_batches(batches)
    df = table.to_pandas()
    return df.sort_values(["id", "time"], kind="stable").reset_index(drop=True)
