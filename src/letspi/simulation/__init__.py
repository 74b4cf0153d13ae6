"""Closed-loop evaluation: log-replay, reactive and hybrid traffic, receding-horizon replanning. SUMO simulates the
reactive and hybrid modes (``engine``); ``closed-loop-log`` runs in NumPy by default (``replay``)."""

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
    "CLOSED_LOOP_MODES", "ClosedLoopChunk", "ClosedLoopConfig", "ClosedLoopStore", "ClosedLoopStoreError",
    "ClosedLoopWorkerError", "DriverModelConfig", "EvaluationMode", "HandoverConfig", "PeriodicReplanner",
    "PlannerSpec", "Replan", "Replanner", "build_planner", "chunk_metrics", "run_closed_loop", "run_closed_loop_to_dir",
    "scored_batch",
]  # fmt: skip
