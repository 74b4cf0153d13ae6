"""Run SUMO through libsumo (in-process; one simulation per process at a time) and read its floating-car data
(FCD CSV, written by SUMO, parsed with pyarrow)."""

from __future__ import annotations

import contextlib
import io
import math
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from letspi.trafficgen.binaries import sumo_binary

STEP_S = 0.04  # 25 Hz, the HighD frame rate
_PROGRESS_CHUNK_S = 10.0  # longest single advance, so progress is reported regularly


@dataclass(frozen=True)
class Collision:
    """A collision SUMO reported: time ``time_s`` [s], SUMO ids ``collider`` and ``victim``, SUMO's ``kind``."""

    time_s: float
    collider: str
    victim: str
    kind: str


@dataclass(frozen=True)
class SimulationResult:
    """FCD of all vehicles on the whole road plus simulator diagnostics. ``fcd``: ``time`` [s], ``id``, ``x``, ``y``
    (front-bumper centre, SUMO axes, y up) [m], ``speed`` [m/s], ``acceleration`` [m/s²], sorted by (id, time);
    ``collisions``: physical contact only; ``wall_time_s``, ``cpu_time_s``: of the stepping [s]; ``events``,
    ``hook_stats``: the hook's ``records`` and ``stats()``."""

    fcd: pd.DataFrame
    collisions: list[Collision]
    wall_time_s: float
    cpu_time_s: float = 0.0
    events: list[Any] = field(default_factory=list)
    hook_stats: dict[str, int] = field(default_factory=dict)


class StepHook(Protocol):
    """What :func:`run_sumo` calls while stepping (the event injector implements it)."""

    records: list[Any]

    def next_wakeup(self) -> float: ...

    def on_step(self, t: float) -> None: ...

    def stats(self) -> dict[str, int]: ...


def import_libsumo() -> Any:
    """Import libsumo quietly (it prints a pyarrow version notice on import; harmless here:
    its Arrow copy is vendored under another soname, and letspi only reads CSV output)."""
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo


def _read_collisions(path: Path) -> list[Collision]:
    if not path.exists() or path.stat().st_size == 0:
        return []
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:  # an empty document (no collisions) can lack the closing tag
        return []
    return [Collision(float(c.get("time", "nan")), c.get("collider", ""), c.get("victim", ""), c.get("type", ""))
            for c in root.iter("collision")]


def run_sumo(
    net_file: Path,
    route_file: Path,
    work_dir: Path,
    *,
    end_s: float,
    seed: int,
    lane_change_duration_s: float = 4.0,
    x_range_m: tuple[float, float] | None = None,
    make_hook: Callable[[Any], StepHook] | None = None,
    ssm_file: Path | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulationResult:
    """Simulate ``[0, end_s)`` at 0.04 s steps with libsumo and return the FCD (rows with SUMO x in ``x_range_m``).
    ``work_dir``: the caller's directory for the FCD, collision and log files. ``lane_change_duration_s`` > 0 makes lane
    changes continuous. ``make_hook`` gets the libsumo module once loaded and returns a ``StepHook`` whose
    ``on_step(t)`` runs whenever SUMO's time t has reached ``next_wakeup()`` (timing as in ``events``). ``ssm_file``:
    every vehicle carries SUMO's SSM device writing TTC, DRAC and PET time lines there (TTC < 5 s, DRAC > 3 m/s² or PET
    < 2 s, within 100 m). ``progress`` gets the fraction of simulated time done."""
    sim = import_libsumo()
    fcd_file = work_dir / "fcd.csv"
    collision_file = work_dir / "collisions.xml"
    cmd = _sumo_command(net_file, route_file, work_dir, end_s=end_s, seed=seed,
                        lane_change_duration_s=lane_change_duration_s, ssm_file=ssm_file)
    report = progress or (lambda _f: None)
    started = time.perf_counter()
    cpu_started = time.process_time()
    sim.start(cmd)
    try:
        hook = make_hook(sim) if make_hook is not None else None
        _step_to_end(sim, end_s, hook, report)
        events = list(hook.records) if hook is not None else []
        stats = hook.stats() if hook is not None else {}
    finally:
        sim.close()
    wall = time.perf_counter() - started
    cpu = time.process_time() - cpu_started
    report(1.0)
    return SimulationResult(fcd=read_fcd(fcd_file, x_range_m=x_range_m), collisions=_read_collisions(collision_file),
                            wall_time_s=wall, cpu_time_s=cpu, events=events, hook_stats=stats)


def _sumo_command(
    net_file: Path, route_file: Path, work_dir: Path, *, end_s: float, seed: int, lane_change_duration_s: float,
    ssm_file: Path | None,
) -> list[str]:
    """SUMO's command line for :func:`run_sumo` (FCD, collisions and log into ``work_dir``)."""
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
        "--collision-output", str(work_dir / "collisions.xml"),
        "--fcd-output", str(work_dir / "fcd.csv"),
        "--fcd-output.attributes", "id,x,y,speed,acceleration",
        "--no-step-log", "true", "--duration-log.disable", "true",
        "--no-warnings", "true",  # emergency-braking notices of scripted events; collisions go to their file
        "--log", str(work_dir / "sumo.log"),
        "--threads", "1",
    ]
    if ssm_file is not None:
        cmd += ["--device.ssm.probability", "1", "--device.ssm.file", str(ssm_file),
                "--device.ssm.measures", "TTC DRAC PET", "--device.ssm.thresholds", "5.0 3.0 2.0",
                "--device.ssm.range", "100", "--device.ssm.trajectories", "true"]
    return cmd


def _step_to_end(sim: Any, end_s: float, hook: StepHook | None, report: Callable[[float], None]) -> None:
    """Step the started simulation to ``end_s`` in chunks, calling the hook's ``on_step`` at each of its wake-ups."""
    t = 0.0
    while t < end_s - 1e-9:
        wake = hook.next_wakeup() if hook is not None else math.inf
        target = min(end_s, t + _PROGRESS_CHUNK_S, max(wake, t + STEP_S))
        # Round up to the step grid: simulationStep(target) runs until time >= target.
        target = math.ceil(target / STEP_S - 1e-6) * STEP_S
        if target - t > 1.5 * STEP_S:
            sim.simulationStep(target)
        else:
            sim.simulationStep()
        t = float(sim.simulation.getTime())
        if hook is not None and t >= wake - 1e-9:
            hook.on_step(t)
        report(min(1.0, t / end_s))


def read_fcd(path: Path, *, x_range_m: tuple[float, float] | None = None) -> pd.DataFrame:
    """A SUMO FCD CSV (';'-separated) as ``time, id, x, y, speed, acceleration`` sorted by (id, time), read in a stream;
    ``x_range_m`` keeps only rows with SUMO x in ``[lo, hi]`` [m]."""
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
