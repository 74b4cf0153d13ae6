"""One episode: highway-env seeded, the ego swapped in, letspi's planner replanning on the recorded scene.

Per replan (every ``EnvSettings.replan_s``): the recorded frames become the planner's view
(``letspi_interop.highway_env.scene.scenario_view``: a history-only scenario of one), the planner plans, and the
ego (``TrackingEgo``) follows the plan, in highway-env's coordinates, over the next simulation frames
(``sim.advance``), each recorded. LLM planners (their kind's ``dual_rate``) run dual-rate as in the closed loop
(``letspi.simulation.schedule.DualRateSchedule``): the model at t = 0 and every ``llm_period_s`` about the scene
then, its answer in force ``llm_latency_s`` later, social force and the shield at every replan with the
parameters in force. highway-env's own egos (``NATIVE_EGOS``) drive themselves; nothing is planned.

The episode ends at the first collision, when the ego leaves the road, when the environment ends it, or at
``duration_s``. Timing (``EpisodeResult.timing``): highway-env's own simulation apart from letspi's adapter,
planning, tracking (the ego's control) and recording, all wall seconds of this process.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from letspi.constants import DT_S, N_FUTURE
from letspi.metrics.config import MetricsConfig
from letspi.metrics.episode import EpisodeInputs, episode_metrics
from letspi.planners.base import PlanBatch, Planner
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.replan import plan_in_batches
from letspi.simulation.schedule import DualRateConfig, DualRatePlanner, DualRateSchedule
from letspi_interop.highway_env import require
from letspi_interop.highway_env.scene import EpisodeTracks, RoadLayout, ScenarioLabel, plan_to_world, scenario_view
from letspi_interop.highway_env.settings import EnvSettings

#: ``EpisodeResult.timing`` keys [s] (``replans_n``: a count)
TIMING_KEYS = ("highway_env_s", "adapter_s", "plan_s", "control_s", "record_s", "wall_s", "replans_n")


@dataclass(frozen=True)
class EpisodeResult:
    """What one episode gives: its metrics (``letspi.metrics.episode.EPISODE_METRICS`` by name), its timing
    (``TIMING_KEYS``), every vehicle's recorded states, the road, and every plan the ego followed.

    plan_t_s: (R,) simulation time each plan was made; plans_xy_m: (R, F, 2) float32, highway-env
    coordinates (point i at plan_t_s + (i + 1) dt); plan_info: per-replan numbers of the planner, name -> (R,).
    """

    seed: int
    metrics: dict[str, Any]
    timing: dict[str, float]
    tracks: EpisodeTracks
    road: RoadLayout
    plan_t_s: np.ndarray
    plans_xy_m: np.ndarray
    plan_info: dict[str, np.ndarray] = field(default_factory=dict)


class EpisodePlanner:
    """A planner replanning one episode: the whole planner at every replan, or dual-rate (module doc)."""

    def __init__(self, planner: Planner, dual_rate: DualRateConfig | None = None, concurrency: int = 1) -> None:
        self.planner = planner
        self.schedule: DualRateSchedule | None = None
        if dual_rate is not None:
            if not isinstance(planner, DualRatePlanner):
                raise TypeError(f"planner {planner.name!r} runs dual-rate but is no DualRatePlanner")
            self.schedule = DualRateSchedule(planner, 1, dual_rate, concurrency)

    def plan(self, view: ScenarioBatch, step: int, last: bool = False) -> tuple[PlanBatch, dict[str, np.ndarray]]:
        """The plan of ``view`` at ``step`` frames (25 Hz) after the episode's start, and its 1-D numeric info."""
        if self.schedule is None:
            plan = plan_in_batches(self.planner, view)
            info = dict(plan.info)
        else:
            planner = self.schedule.planner
            context = planner.context(view)
            proposals, info = self.schedule.step(step, view, context)
            if last:
                self.schedule.finish(info)
            plan = planner.simulate(view, context, proposals)
            info = {**plan.info, **info}
        kept = {k: np.asarray(v) for k, v in info.items()}
        return plan, {k: v for k, v in kept.items() if v.ndim == 1 and v.dtype.kind in "biuf"}

    def close(self) -> None:
        if self.schedule is not None:
            self.schedule.close()


def _label(settings: EnvSettings, seed: int) -> ScenarioLabel:
    return ScenarioLabel(f"{settings.tag}_s{seed}", int(seed) % 2**31, f"{settings.tag}_s{seed}")


def run_episode(settings: EnvSettings, seed: int, *, planner: EpisodePlanner | None = None, ego_kind: str = "plan",
                config: MetricsConfig | None = None) -> EpisodeResult:
    """One episode of ``settings`` seeded ``seed``: driven by ``planner`` (through ``TrackingEgo``) or, without
    one, by highway-env's ego ``ego_kind`` (``"idm"``, ``"lane-keeper"``)."""
    require()
    import letspi_interop.highway_env.sim as hesim  # highway-env at module level: only where an episode runs

    started = time.perf_counter()
    env = hesim.make_env(settings.env_id, settings.env_config())
    env.reset(seed=int(seed))
    road = hesim.road_layout(env)
    ego = hesim.install_ego(env, "plan" if planner is not None else ego_kind)  # type: ignore[arg-type]
    frames = settings.frames_per_replan
    recorder = hesim.Recorder(env, settings.max_replans * frames + 1)
    label = _label(settings, seed)
    timing = dict.fromkeys(TIMING_KEYS, 0.0)
    plan_t: list[float] = []
    plans: list[np.ndarray] = []
    infos: list[dict[str, np.ndarray]] = []
    latency: list[float] = []
    try:
        for k in range(settings.max_replans):
            if hesim.ended(env):
                break
            if planner is not None:
                _replan(planner, recorder.tracks(), road, label, ego, k == settings.max_replans - 1,
                        (timing, plan_t, plans, infos, latency))
            step = hesim.advance(env, recorder, frames)
            timing["highway_env_s"] += step.highway_env_s
            timing["control_s"] += step.control_s
            timing["record_s"] += step.record_s
    finally:
        if planner is not None:
            planner.close()
        env.close()
    tracks = recorder.tracks()
    timing["replans_n"] = float(len(plans))
    timing["wall_s"] = time.perf_counter() - started
    metrics = episode_metrics(EpisodeInputs(tracks.t_s, tracks.xy_m, tracks.vxy_mps, tracks.length_m, tracks.width_m,
                                            tracks.ego, tracks.crashed, tracks.ego_on_road,
                                            road.lane_index(tracks.xy_m[tracks.ego, :, 1]), np.asarray(latency)),
                              config)
    keys = set.intersection(*(set(i) for i in infos)) if infos else set()
    return EpisodeResult(
        seed=int(seed), metrics=metrics, timing=timing, tracks=_copied(tracks), road=road,
        plan_t_s=np.asarray(plan_t, dtype=np.float64),
        plans_xy_m=np.asarray(plans, dtype=np.float32).reshape(len(plans), N_FUTURE, 2),
        plan_info={key: np.concatenate([i[key] for i in infos]) for key in sorted(keys)},
    )


def _replan(planner: EpisodePlanner, tracks: EpisodeTracks, road: RoadLayout, label: ScenarioLabel, ego: Any,
            last: bool, out: tuple[dict[str, float], list[float], list[np.ndarray], list[dict[str, np.ndarray]],
                                   list[float]]) -> None:
    """One replan: the view, the plan, the ego told to follow it; timing and the plan appended to ``out``."""
    import letspi_interop.highway_env.sim as hesim

    timing, plan_t, plans, infos, latency = out
    t0 = time.perf_counter()
    view = scenario_view(tracks, road, label)
    t1 = time.perf_counter()
    now_s = float(tracks.t_s[-1])
    plan, info = planner.plan(view, round(now_s / DT_S), last)
    t2 = time.perf_counter()
    centre = tracks.xy_m[tracks.ego, -1]
    xy, vxy = plan_to_world(plan.xy_m[0], plan.vxy_mps[0], centre)
    times = now_s + np.arange(N_FUTURE + 1) * DT_S
    ego.follow(hesim.Plan(times, np.vstack([centre, xy]), np.vstack([tracks.vxy_mps[tracks.ego, -1], vxy])))
    timing["adapter_s"] += (t1 - t0) + (time.perf_counter() - t2)
    timing["plan_s"] += t2 - t1
    latency.append(t2 - t1)
    plan_t.append(now_s)
    plans.append(xy.astype(np.float32))
    infos.append(info)


def _copied(tracks: EpisodeTracks) -> EpisodeTracks:
    """The tracks in arrays of their own (the recorder's buffers are larger)."""
    return EpisodeTracks(tracks.t_s.copy(), tracks.xy_m.copy(), tracks.vxy_mps.copy(), tracks.heading_rad.copy(),
                         tracks.crashed.copy(), tracks.ids.copy(), tracks.length_m.copy(), tracks.width_m.copy(),
                         tracks.ego, tracks.ego_on_road.copy())
