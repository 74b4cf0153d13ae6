"""Closed-loop evaluation: log-replay, reactive and hybrid traffic, receding-horizon replanning.

SUMO simulates the reactive and hybrid modes (``letspi.simulation.engine``); ``closed-loop-log``, where
nobody but the ego moves off its log, runs in NumPy by default (``letspi.simulation.replay``, the same
results; ``ClosedLoopConfig.simulator``).

Public API:

* ``run_closed_loop(planner_spec, batch, config)``:
  an iterator of ``ClosedLoopChunk`` (simulated ego and neighbours, every plan, SUMO collisions);
* ``chunk_metrics`` / ``scored_batch``: the open-loop metric code on the simulated trajectories;
* ``run_closed_loop_to_dir`` / ``ClosedLoopStore``: resumable per-chunk output;
* ``PlannerSpec`` / ``build_planner``: the picklable planner description workers build from;
* ``ClosedLoopConfig``, ``EvaluationMode``, ``DriverModelConfig``, ``HandoverConfig``;
* ``Replanner`` / ``Replan`` / ``PeriodicReplanner``: the engine's replanning step (``letspi.simulation.replan``).
"""

from letspi.simulation.config import (
    CLOSED_LOOP_MODES,
    ClosedLoopConfig,
    DriverModelConfig,
    EvaluationMode,
    HandoverConfig,
)
from letspi.simulation.pool import ClosedLoopWorkerError
from letspi.simulation.replan import PeriodicReplanner, Replan, Replanner
from letspi.simulation.result import ClosedLoopChunk, chunk_metrics, scored_batch
from letspi.simulation.run import run_closed_loop
from letspi.simulation.spec import PlannerSpec, build_planner
from letspi.simulation.store import ClosedLoopStore, ClosedLoopStoreError, run_closed_loop_to_dir

__all__ = [
    "CLOSED_LOOP_MODES",
    "ClosedLoopChunk",
    "ClosedLoopConfig",
    "ClosedLoopStore",
    "ClosedLoopStoreError",
    "ClosedLoopWorkerError",
    "DriverModelConfig",
    "EvaluationMode",
    "HandoverConfig",
    "PeriodicReplanner",
    "PlannerSpec",
    "Replan",
    "Replanner",
    "build_planner",
    "chunk_metrics",
    "run_closed_loop",
    "run_closed_loop_to_dir",
    "scored_batch",
]
