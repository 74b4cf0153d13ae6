"""Generate HighD-format recordings of a two-direction highway with SUMO: ``network`` -> ``demand`` -> ``simulate``
with ``events`` -> ``convert`` -> ``letspi.highd.derive.build_recording`` -> ``letspi.highd.io.write_recording``.

No contact, ever: a run with a SUMO collision or overlapping boxes in the window is re-simulated with a sub-seed
(``derived_seed``), up to ``TrafficConfig.max_attempts`` runs; then generation fails naming the seed and contacts."""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from letspi import __version__
from letspi.highd.contacts import overlapping_boxes
from letspi.highd.derive import build_recording
from letspi.highd.events import EVENTS_COLUMNS, write_events
from letspi.highd.generation import write_generation
from letspi.highd.io import write_highway_image, write_recording
from letspi.trafficgen.config import TrafficConfig, traffic_preset
from letspi.trafficgen.convert import ImageTracks, clip_to_window, fcd_to_image
from letspi.trafficgen.demand import (
    DEFAULT_FLOW_PER_LANE_VEH_PER_H,
    DemandConfig,
    VehicleSpec,
    sample_demand,
    write_routes,
)
from letspi.trafficgen.events import EventInjector, EventRecord, VehicleInfo, Window
from letspi.trafficgen.network import HighwayGeometry, HighwayNetwork, build_network
from letspi.trafficgen.simulate import STEP_S, Collision, SimulationResult, run_sumo

FRAME_RATE_HZ = 25
_TAIL_S = 6.0  # > lane-change duration (4 s)
_X_MARGIN_M = 250.0  # FCD kept around the window: covers any lane-change ramp (4 s at <= 60 m/s)
DEFAULT_WARMUP_S = 90.0  # > time for a truck (about 22 m/s) to cover approach + window (1,120 m)


def default_flow_veh_per_h(lanes_per_direction: int) -> float:
    """Default demand per direction [veh/h]: about 733 veh/h per lane (2,200 on 3 lanes, 1,467 on 2)."""
    return DEFAULT_FLOW_PER_LANE_VEH_PER_H * lanes_per_direction


def derived_seed(seed: int, attempt: int) -> int:
    """Seed of re-simulation ``attempt`` (0 = the seed itself)."""
    if attempt == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(attempt)]).generate_state(1)[0] % (2**31 - 1))


@dataclass
class SimulatedRecordings:
    """Everything a generation run produced in memory, before writing. ``chunks``: one ``(states, vehicles)`` per
    recording (``clip_to_window``); ``first_steps``: the simulation step of each recording's frame 1; ``events``: per
    recording, in HighD frames but with SUMO ids and lane indices; ``collisions``: SUMO's in the accepted run (always
    empty); ``sim_*_time_s``: all attempts [s]; ``attempt``: the accepted one (0 = the seed); ``rejected``: why each
    earlier one was; ``network.net_file`` is deleted."""
    network: HighwayNetwork
    chunks: list[tuple[pd.DataFrame, pd.DataFrame]] = field(default_factory=list)
    first_steps: list[int] = field(default_factory=list)
    events: list[pd.DataFrame] = field(default_factory=list)
    collisions: list[Collision] = field(default_factory=list)
    sim_wall_time_s: float = 0.0
    sim_cpu_time_s: float = 0.0
    attempt: int = 0
    rejected: list[str] = field(default_factory=list)
    failed_events: int = 0
    perceived_lane_changes: int = 0


def _window(network: HighwayNetwork) -> Window:
    x0 = network.window_x0_m
    return Window(x0, x0 + network.geometry.window_m, network.east_centres_y_m, network.west_centres_y_m)


def _event_table(records: list[EventRecord], first_step: int, n_steps: int) -> pd.DataFrame:
    """Events of one recording chunk, frames relative to the chunk (SUMO ids kept)."""
    rows = []
    for r in records:
        step = round(r.time_s / STEP_S)
        if first_step <= step < first_step + n_steps and r.kind != "failed":
            rows.append({"frame": step - first_step + 1, "sumo_id": r.actor, "kind": r.kind,
                         "other_sumo_id": r.other, "lane": r.lane, "target_lane": r.target_lane,
                         "speed_mps": r.speed_mps, "target_speed_mps": r.target_speed_mps,
                         "decel_mps2": r.decel_mps2, "duration_s": r.duration_s, "gap_m": r.gap_m,
                         "reaction_s": r.reaction_s, "held_s": r.held_s,
                         "other_decel_mps2": r.other_decel_mps2})
    return pd.DataFrame(rows, columns=["frame", "sumo_id", "kind", "other_sumo_id", "lane", "target_lane",
                                       "speed_mps", "target_speed_mps", "decel_mps2", "duration_s", "gap_m",
                                       "reaction_s", "held_s", "other_decel_mps2"])


def _simulate_once(
    tmp: Path, *, seed: int, network: HighwayNetwork, flow: float, traffic: TrafficConfig,
    end_s: float, warmup_s: float, progress: Callable[[float], None], ssm_file: Path | None = None,
) -> tuple[list[VehicleSpec], ImageTracks, SimulationResult]:
    # Two independent streams: adding events does not change the drawn demand.
    rng_demand = np.random.default_rng(seed)
    rng_events = np.random.default_rng([seed, 1])
    demand = DemandConfig(truck_share=traffic.truck_share, drivers=traffic.drivers)
    specs = sample_demand(rng_demand, entries=network.entries, flow_veh_per_h=flow, end_s=end_s, config=demand)
    routes = tmp / "highway.rou.xml"
    write_routes(routes, specs, network.routes,
                 lc_strategic=None if traffic.layout.kind == "straight" else traffic.layout.lc_strategic)
    info = {s.vid: VehicleInfo(s.length_m, s.east, s.kind == "truck", s.reaction_time_s) for s in specs}

    def make_hook(sim: object) -> EventInjector:
        return EventInjector(sim=sim, config=traffic.events, rng=rng_events, window=_window(network),
                             vehicles=info, start_s=warmup_s, end_s=end_s - _TAIL_S,
                             lane_change_perception=traffic.drivers.lane_change_perception)

    x0 = network.window_x0_m
    needs_hook = traffic.events.any_enabled or traffic.drivers.lane_change_perception
    sim = run_sumo(network.net_file, routes, tmp, end_s=end_s, seed=seed,
                   x_range_m=(x0 - _X_MARGIN_M, x0 + network.geometry.window_m + _X_MARGIN_M),
                   make_hook=make_hook if needs_hook else None, ssm_file=ssm_file, progress=progress)
    return specs, fcd_to_image(sim.fcd, specs, network), sim


def simulate_recordings(
    *,
    minutes: float = 3.0,
    seed: int = 0,
    lanes_per_direction: int = 3,
    flow_veh_per_h: float | None = None,
    recording_minutes: float | None = None,
    warmup_s: float = DEFAULT_WARMUP_S,
    geometry: HighwayGeometry | None = None,
    traffic: TrafficConfig | None = None,
    ssm_file: Path | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimulatedRecordings:
    """Simulate and cut recordings in memory (no derived columns; see ``generate_highd``); ``ssm_file``: SUMO's SSM
    device output of the accepted attempt."""
    _check_request(minutes, lanes_per_direction, recording_minutes)
    cfg = traffic or traffic_preset("highd")
    geo = geometry or HighwayGeometry()
    if geo.lanes_per_direction != lanes_per_direction:
        geo = replace(geo, lanes_per_direction=lanes_per_direction)
    flow = default_flow_veh_per_h(lanes_per_direction) if flow_veh_per_h is None else flow_veh_per_h
    if flow <= 0:
        raise ValueError(f"flow_veh_per_h must be > 0, got {flow}")

    end_s, starts, lengths = _timeline(minutes, warmup_s, recording_minutes)
    report = progress or (lambda _f: None)
    report(0.0)
    tmp = Path(tempfile.mkdtemp(prefix="letspi_sumo_"))
    try:
        network = build_network(tmp, geo, cfg.layout)
        result = SimulatedRecordings(network=network)
        upper = (float(network.upper_markings_y_m[0]), float(network.upper_markings_y_m[-1]))
        lower = (float(network.lower_markings_y_m[0]), float(network.lower_markings_y_m[-1]))
        for attempt in range(cfg.max_attempts):
            lo, hi = attempt / cfg.max_attempts, (attempt + 1) / cfg.max_attempts
            sub_seed = derived_seed(seed, attempt)

            def attempt_progress(f: float, lo: float = lo, hi: float = hi) -> None:
                report(0.9 * (lo + (hi - lo) * f))

            _, tracks, sim = _simulate_once(tmp, seed=sub_seed, network=network, flow=flow, traffic=cfg,
                                            end_s=end_s, warmup_s=warmup_s, progress=attempt_progress,
                                            ssm_file=ssm_file)
            result.sim_wall_time_s += sim.wall_time_s
            result.sim_cpu_time_s += sim.cpu_time_s
            chunks = [clip_to_window(tracks, first_step=s, n_steps=n, window_m=geo.window_m, upper_y_m=upper,
                                     lower_y_m=lower) for s, n in zip(starts, lengths, strict=True)]
            contact = _contact(sim, chunks)
            if contact is None:
                _accept(result, attempt, sim, chunks, starts, lengths)
                report(0.9)
                return result
            result.rejected.append(f"attempt {attempt} (seed {sub_seed}): {contact}")
        raise RuntimeError(f"seed {seed}: every one of {cfg.max_attempts} simulation attempts had contact; "
                           + "; ".join(result.rejected))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _timeline(minutes: float, warmup_s: float, recording_minutes: float | None) -> tuple[float, list[int], list[int]]:
    """(simulation end [s], first step of each recording, its number of steps)."""
    record_steps = round(minutes * 60.0 / STEP_S)
    first_step = round(warmup_s / STEP_S)
    # Run a little past the last recorded frame so lane changes in progress there complete
    # (their smoothing needs the end anchor).
    end_s = (first_step + record_steps) * STEP_S + _TAIL_S
    chunk_steps = record_steps if recording_minutes is None else max(1, round(recording_minutes * 60.0 / STEP_S))
    starts = list(range(first_step, first_step + record_steps, chunk_steps))
    return end_s, starts, [min(chunk_steps, first_step + record_steps - s) for s in starts]


def _accept(result: SimulatedRecordings, attempt: int, sim: SimulationResult,
            chunks: list[tuple[pd.DataFrame, pd.DataFrame]], starts: list[int], lengths: list[int]) -> None:
    result.chunks = chunks
    result.first_steps = list(starts)
    result.events = [_event_table(sim.events, s, n) for s, n in zip(starts, lengths, strict=True)]
    result.attempt = attempt
    result.failed_events = sim.hook_stats.get("failed_lane_changes", 0)
    result.perceived_lane_changes = sim.hook_stats.get("perceived_lane_changes", 0)


def _check_request(minutes: float, lanes_per_direction: int, recording_minutes: float | None) -> None:
    if minutes <= 0:
        raise ValueError(f"minutes must be > 0, got {minutes}")
    if lanes_per_direction not in (2, 3):
        raise ValueError(f"lanes_per_direction must be 2 or 3, got {lanes_per_direction}")
    if recording_minutes is not None and recording_minutes <= 0:
        raise ValueError(f"recording_minutes must be > 0, got {recording_minutes}")


def _contact(sim: SimulationResult, chunks: list[tuple[pd.DataFrame, pd.DataFrame]]) -> str | None:
    """Why a simulation attempt is rejected (a SUMO collision, or boxes overlapping in the written
    window), None when it has no contact."""
    n_overlap = sum(len(overlapping_boxes(states)) for states, _ in chunks)
    if not sim.collisions and n_overlap == 0:
        return None
    first = sim.collisions[0] if sim.collisions else None
    return (f"SUMO collision at t={first.time_s:.2f} s between {first.collider} and {first.victim} "
            f"({len(sim.collisions)} in total)" if first else f"{n_overlap} overlapping box pair-frames")


def _highd_lane_id(network: HighwayNetwork, east: bool, lane_index: int) -> int:
    """HighD laneId of a main SUMO lane index (0 = rightmost) of one carriageway."""
    centres = network.east_centres_y_m if east else network.west_centres_y_m
    image_y = network.image_y_ref_m - float(centres[lane_index])
    markings = np.sort(np.concatenate([network.upper_markings_y_m, network.lower_markings_y_m]))
    return int(1 + np.searchsorted(np.round(markings, 2), image_y, side="left"))


def _highd_events(table: pd.DataFrame, vehicles: pd.DataFrame, states: pd.DataFrame,
                  network: HighwayNetwork) -> pd.DataFrame:
    """Map SUMO ids to HighD ids; keep events whose actor is in the recording at the start frame."""
    id_of = dict(zip(vehicles["sumo_id"], vehicles["id"], strict=True))
    present = set(zip(states["id"].to_numpy().tolist(), states["frame"].to_numpy().tolist(), strict=True))
    rows = []
    for r in table.to_dict("records"):
        vid = id_of.get(r["sumo_id"])
        if vid is None or (vid, r["frame"]) not in present:
            continue
        east = str(r["sumo_id"]).startswith("E")
        rows.append({**{k: r[k] for k in ("kind", "speed_mps", "target_speed_mps", "decel_mps2", "duration_s",
                                          "gap_m", "reaction_s", "held_s", "other_decel_mps2")},
                     "frame": int(r["frame"]), "id": int(vid), "other_id": int(id_of.get(r["other_sumo_id"], 0)),
                     "lane_id": _highd_lane_id(network, east, int(r["lane"])),
                     "target_lane_id": _highd_lane_id(network, east, int(r["target_lane"]))})
    return pd.DataFrame(rows, columns=list(EVENTS_COLUMNS))


@dataclass(frozen=True)
class GenerationReport:
    """What ``generate_highd`` wrote (``paths``: the ``NN_recordingMeta.csv`` files in order) and how long it took. Wall
    and SUMO times [s] cover all attempts; ``attempt`` (accepted) and ``rejected`` as in ``SimulatedRecordings``;
    ``failed_events``: forced lane changes SUMO refused; ``perceived_lane_changes``: followers held by perception."""

    paths: list[Path]
    simulated_minutes: float
    wall_time_s: float
    sumo_wall_time_s: float
    sumo_cpu_time_s: float
    attempt: int
    rejected: list[str]
    events_written: int
    failed_events: int
    perceived_lane_changes: int

    @property
    def sim_minutes_per_wall_s(self) -> float:
        return self.simulated_minutes / self.wall_time_s if self.wall_time_s > 0 else float("nan")


def _write_recordings(sim: SimulatedRecordings, out: Path, report: Callable[[float], None],
                      generation: dict[str, Any]) -> tuple[list[Path], int]:
    """Derive and write each recording, its events file, its road image and its generation record
    (``generation`` plus the recording's first simulation step); (the recordingMeta paths, events written)."""
    written: list[Path] = []
    n_events = 0
    for k, ((states, vehicles), table) in enumerate(zip(sim.chunks, sim.events, strict=True), start=1):
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
        events = _highd_events(table, vehicles, states, sim.network)
        write_events(events, out, k)
        write_highway_image(out, k, sim.network.upper_markings_y_m.tolist(), sim.network.lower_markings_y_m.tolist(),
                            sim.network.geometry.window_m)
        write_generation({**generation, "recording": k, "first_step": sim.first_steps[k - 1]}, out, k)
        n_events += len(events)
        written.extend(p for p in paths if p.name.endswith("_recordingMeta.csv"))
        report(0.9 + 0.1 * k / len(sim.chunks))
    return written, n_events


def generate_highd(
    out_dir: Path,
    *,
    minutes: float = 3.0,
    seed: int = 0,
    lanes_per_direction: int = 3,
    flow_veh_per_h: float | None = None,
    recording_minutes: float | None = None,
    criticality: str = "highd",
    traffic: TrafficConfig | None = None,
    progress: Callable[[float], None] | None = None,
) -> GenerationReport:
    """Simulate a two-direction highway and write HighD-format recordings (``NN_tracks.csv``, ``NN_tracksMeta.csv``,
    ``NN_recordingMeta.csv``, ``NN_events.csv``, ``NN_highway.png``, ``NN_generation.json``) into ``out_dir``.

    ``minutes`` are recorded after a 90 s warm-up; equal seeds give identical files; ``flow_veh_per_h`` per
    direction defaults to about 733 per lane; ``recording_minutes`` splits the run (vehicles crossing a split are
    cut); ``criticality`` names a preset, ignored when ``traffic`` is given. A vehicle is recorded while its whole
    box is inside the 420 m window and its centre on the main carriageway; no speed limit (speedLimit -1)."""
    started = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report = progress or (lambda _f: None)
    cfg = traffic or traffic_preset(criticality)
    sim = simulate_recordings(minutes=minutes, seed=seed, lanes_per_direction=lanes_per_direction,
                              flow_veh_per_h=flow_veh_per_h, recording_minutes=recording_minutes,
                              traffic=cfg, progress=lambda f: report(0.9 * f))
    generation = {"generator": "letspi.trafficgen", "letspi_version": __version__, "seed": seed,
                  "minutes": minutes, "lanes_per_direction": lanes_per_direction,
                  "flow_veh_per_h": flow_veh_per_h, "recording_minutes": recording_minutes,
                  "attempt": sim.attempt, "traffic": cfg.to_dict()}
    written, n_events = _write_recordings(sim, out, report, generation)
    return GenerationReport(paths=written, simulated_minutes=float(minutes), wall_time_s=time.perf_counter() - started,
                            sumo_wall_time_s=sim.sim_wall_time_s, sumo_cpu_time_s=sim.sim_cpu_time_s,
                            attempt=sim.attempt, rejected=sim.rejected, events_written=n_events,
                            failed_events=sim.failed_events, perceived_lane_changes=sim.perceived_lane_changes)
