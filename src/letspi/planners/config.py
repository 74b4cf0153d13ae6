"""The kind-neutral part of planner configurations: the physics building blocks (``letspi.physics.config``,
re-exported), the prediction options and the ``PlannerConfig`` protocol; each kind's own sits in its module."""

from __future__ import annotations

from typing import Any, Protocol

from letspi.keyed import Config
from letspi.physics.config import GoalsConfig, GoalSource, SfParamsConfig, WeightsConfig
from letspi.physics.neighbours import NeighbourPredictionMode
from letspi.planners.options import PlannerOption, file_option

__all__ = ["GoalSource", "GoalsConfig", "SfParamsConfig", "WeightsConfig"]

GOAL_SOURCES: tuple[str, ...] = ("learned", "kinematic", "oracle", "mobil")
GOAL_WEIGHTS_ENV = "LETSPI_GOAL_WEIGHTS"

# Options of the planners that predict goals and neighbours (every kind but human and cv) -----------
NEIGHBOURS = PlannerOption(
    "neighbour_mode", str, NeighbourPredictionMode.IDM.value,
    "Neighbour prediction of the planners: ground_truth_oracle leaks the future (an upper bound, not a planner)",
    flag="--neighbours", choices=tuple(m.value for m in NeighbourPredictionMode))
GOALS = PlannerOption(
    "goals", str, "learned",
    "Goal source: learned (the goal predictor's weights, see --goal-weights), kinematic, mobil (where an IDM "
    "driver with MOBIL lane changes would be), or oracle (the true endpoint: leaks the future)", choices=GOAL_SOURCES)
GOAL_WEIGHTS = file_option(
    "goal_weights",
    f"Weights of the learned goal predictor (from `letspi train goals`; default: ${GOAL_WEIGHTS_ENV}, else the "
    "shipped ones)")
SF_PARAMS = file_option(
    "sf_params_file",
    "Fitted social force parameters JSON (from `letspi fit sf`; default: the shipped fit); the LLM planners take "
    "r_col and their fallback from it", flag="--sf-params")
#: what every planner that predicts goals and neighbours reads
PREDICTION_OPTIONS: tuple[PlannerOption[Any], ...] = (NEIGHBOURS, GOALS, GOAL_WEIGHTS)
#: what the fixed-parameter social force planners read (``sf``, ``sf-opt``)
SOCIAL_FORCE_OPTIONS: tuple[PlannerOption[Any], ...] = (*PREDICTION_OPTIONS, SF_PARAMS)


class SocialForcePlannerFields(Config):
    """What every fixed-parameter social force planner is built from (``sf``, ``sf-opt``, ``mlp``)."""

    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    goals: GoalsConfig
    sf_params: SfParamsConfig


class PlannerConfig(Protocol):
    """What every planner configuration offers: a frozen ``Config`` whose ``kind`` field is a literal
    naming its entry in ``letspi.assembly.planner_table``."""

    @property
    def kind(self) -> str: ...

    def identity(self) -> dict[str, Any]: ...

    def key(self) -> str: ...

    def record(self) -> dict[str, Any]: ...
