"""Generate HighD-format recordings of a straight two-direction highway with SUMO.

Pipeline: :mod:`network` (netconvert, plain XML) -> :mod:`demand` (seeded vehicles) ->
:mod:`simulate` (SUMO CLI, FCD at 25 Hz) -> :mod:`convert` (image axes, 420 m window) ->
``letspi.highd.derive.build_recording`` (lanes, neighbours, dhw/thw/ttc, metas) ->
``letspi.highd.io.write_recording``.

Timeline: the simulation runs ``warmup_s`` + ``minutes`` * 60 seconds; recording starts after the
warm-up so the road is populated, and every vehicle has driven ``approach_m`` (700 m) before it
enters the window, so it arrives at speed, in a lane chosen by the lane-change model and with
car-following spacing.

Determinism: a seed fixes the demand (numpy generator) and SUMO's seed; SUMO runs with sigma = 0
(EIDM with its driver-error processes off) and one thread, so equal seeds give identical files.
"""

from __future__ import annotations

import shutil
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.highd.derive import build_recording
from letspi.highd.io import write_recording
from letspi.sumo.convert import ImageTracks, clip_to_window, fcd_to_image
from letspi.sumo.demand import DEFAULT_FLOW_PER_LANE_VEH_PER_H, DemandConfig, sample_demand, write_routes
from letspi.sumo.network import HighwayGeometry, HighwayNetwork, build_network
from letspi.sumo.simulate import STEP_S, run_sumo

FRAME_RATE_HZ = 25
_TAIL_S = 6.0  # > lane-change duration (4 s)
_X_MARGIN_M = 250.0  # FCD kept around the window: covers any lane-change ramp (4 s at <= 60 m/s)
DEFAULT_WARMUP_S = 90.0  # > time for a truck (about 22 m/s) to cover approach + window (1,120 m)


def default_flow_veh_per_h(lanes_per_direction: int) -> float:
    """Default demand per direction [veh/h]: about 733 veh/h per lane (2,200 on 3 lanes, 1,467 on 2)."""
    return DEFAULT_FLOW_PER_LANE_VEH_PER_H * lanes_per_direction


@dataclass
class SimulatedRecordings:
    """Everything a generation run produced in memory (before writing).

    Attributes:
        network: the road (markings, transform). Its ``net_file`` is deleted after the run.
        chunks: one ``(states, vehicles)`` pair per recording, see :func:`clip_to_window`.
        collisions: collisions reported by SUMO.
        sim_wall_time_s: wall time of the SUMO run [s].
    """

    network: HighwayNetwork
    chunks: list[tuple[pd.DataFrame, pd.DataFrame]] = field(default_factory=list)
    collisions: int = 0
    sim_wall_time_s: float = 0.0


def simulate_recordings(
    *,
    minutes: float = 3.0,
    seed: int = 0,
    lanes_per_direction: int = 3,
    flow_veh_per_h: float | None = None,
    recording_minutes: float | None = None,
    warmup_s: float = DEFAULT_WARMUP_S,
    geometry: HighwayGeometry | None = None,
    demand: DemandConfig | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulatedRecordings:
    """Simulate and cut recordings in memory (no derived columns). See :func:`generate_recordings`."""
    if minutes <= 0:
        raise ValueError(f"minutes must be > 0, got {minutes}")
    if lanes_per_direction not in (2, 3):
        raise ValueError(f"lanes_per_direction must be 2 or 3, got {lanes_per_direction}")
    if recording_minutes is not None and recording_minutes <= 0:
        raise ValueError(f"recording_minutes must be > 0, got {recording_minutes}")
    geo = geometry or HighwayGeometry()
    if geo.lanes_per_direction != lanes_per_direction:
        geo = HighwayGeometry(**{**geo.__dict__, "lanes_per_direction": lanes_per_direction})
    flow = default_flow_veh_per_h(lanes_per_direction) if flow_veh_per_h is None else flow_veh_per_h
    if flow <= 0:
        raise ValueError(f"flow_veh_per_h must be > 0, got {flow}")

    record_steps = round(minutes * 60.0 / STEP_S)
    first_step = round(warmup_s / STEP_S)
    # Run a little past the last recorded frame so lane changes in progress there complete
    # (their smoothing needs the end anchor).
    end_s = (first_step + record_steps) * STEP_S + _TAIL_S
    chunk_steps = record_steps if recording_minutes is None else max(1, round(recording_minutes * 60.0 / STEP_S))

    report = progress or (lambda _f: None)
    report(0.0)
    rng = np.random.default_rng(seed)
    tmp = Path(tempfile.mkdtemp(prefix="letspi_sumo_"))
    try:
        network = build_network(tmp, geo)
        specs = sample_demand(rng, lanes_per_direction=lanes_per_direction, flow_veh_per_h=flow,
                              end_s=end_s, config=demand)
        routes = tmp / "highway.rou.xml"
        write_routes(routes, specs)
        report(0.02)
        sim = run_sumo(network.net_file, routes, tmp, end_s=end_s, seed=seed,
                       x_range_m=(network.window_x0_m - _X_MARGIN_M,
                                  network.window_x0_m + geo.window_m + _X_MARGIN_M),
                       progress=lambda f: report(0.02 + 0.78 * f))
        tracks: ImageTracks = fcd_to_image(sim.fcd, specs, network)
        report(0.9)
        if sim.collisions:
            # Never seen with the default demand; kept visible rather than silently written.
            warnings.warn(f"SUMO reported {sim.collisions} collision(s); boxes may overlap",
                          RuntimeWarning, stacklevel=2)
        result = SimulatedRecordings(network=network, collisions=sim.collisions,
                                     sim_wall_time_s=sim.wall_time_s)
        for start in range(first_step, first_step + record_steps, chunk_steps):
            n = min(chunk_steps, first_step + record_steps - start)
            result.chunks.append(clip_to_window(tracks, first_step=start, n_steps=n,
                                                window_m=geo.window_m))
        return result
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def generate_recordings(
    out_dir: Path,
    *,
    minutes: float = 3.0,
    seed: int = 0,
    lanes_per_direction: int = 3,
    flow_veh_per_h: float | None = None,
    recording_minutes: float | None = None,
    progress: Callable[[float], None] | None = None,
) -> list[Path]:
    """Simulate a straight highway and write HighD-format recordings into ``out_dir``.

    Args:
        out_dir: output directory (created if missing); receives ``NN_tracks.csv``,
            ``NN_tracksMeta.csv`` and ``NN_recordingMeta.csv`` for NN = 01, 02, ...
        minutes: recorded (simulated) minutes, after a 90 s warm-up.
        seed: random seed; equal seeds give identical recordings.
        lanes_per_direction: 2 or 3 lanes per carriageway.
        flow_veh_per_h: demand per direction [veh/h]; default about 733 veh/h per lane
            (2,200 on 3 lanes), free flow with frequent interactions.
        recording_minutes: split the run into consecutive recordings of this length
            (the last may be shorter); default one recording for the whole run. Vehicles
            crossing a split are cut, as in real recordings.
        progress: called with the fraction done, in [0, 1].

    Returns:
        Paths of the written ``NN_recordingMeta.csv`` files, in recording order.

    Vehicles are cars, vans and trucks; HighD has only "Car"/"Truck", so vans are written as
    "Car" with van dimensions. The window is 420 m long (image x in [0, 420]); a vehicle is in a
    frame when its whole box is inside. Direction 1 drives towards -x on the upper lanes,
    direction 2 towards +x on the lower lanes. No speed limit (speedLimit -1).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report = progress or (lambda _f: None)
    sim = simulate_recordings(minutes=minutes, seed=seed, lanes_per_direction=lanes_per_direction,
                              flow_veh_per_h=flow_veh_per_h, recording_minutes=recording_minutes,
                              progress=lambda f: report(0.9 * f))
    written: list[Path] = []
    for k, (states, vehicles) in enumerate(sim.chunks, start=1):
        rec = build_recording(
            states, vehicles[["id", "class", "drivingDirection"]],
            recording_id=k,
            upper_markings_y_m=sim.network.upper_markings_y_m.tolist(),
            lower_markings_y_m=sim.network.lower_markings_y_m.tolist(),
            frame_rate_hz=FRAME_RATE_HZ,
            location_id=0,
            speed_limit_mps=-1.0,
        )
        paths = write_recording(rec, out)
        written.extend(p for p in paths if p.name.endswith("_recordingMeta.csv"))
        report(0.9 + 0.1 * k / len(sim.chunks))
    return written
