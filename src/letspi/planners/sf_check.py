"""``sf-check``: ``letspi-fast``'s presets, checks, gate and shield, choosing by ``rule_choice`` without a model
(an ablation: how much of LetsPi's gain the physics gives alone)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from letspi.method.config import DecisionConfig
from letspi.method.decide import Decider, GatedChecks
from letspi.method.phases import decision_reason
from letspi.metrics.registry import Metric
from letspi.physics.params import SocialForceParams
from letspi.planners.base import PlanBatch, PlanningContext, PredictingPlanner, Proposals
from letspi.planners.config import SOCIAL_FORCE_OPTIONS, SocialForcePlannerFields
from letspi.planners.decision import DECISION_OPTIONS, DECISION_OUTPUTS, decision_info
from letspi.planners.llm import (
    PRESETS_CHECKED,
    PRESETS_PASS_ALL,
    PRESETS_PROGRESS,
    PROPOSED_GOALS,
    PROPOSED_VXY,
    PROPOSED_XY,
    SHIELD,
    SHIELD_OUTPUTS,
    SHIELD_PRESETS,
    simulate_and_shield,
)
from letspi.planners.options import PlannerOption
from letspi.scenario.types import ScenarioBatch

OPTIONS: tuple[PlannerOption[Any], ...] = (*SOCIAL_FORCE_OPTIONS, *DECISION_OPTIONS, SHIELD, SHIELD_PRESETS)
OUTPUTS: tuple[Metric, ...] = (*DECISION_OUTPUTS, *SHIELD_OUTPUTS)


class SfCheckConfig(SocialForcePlannerFields):
    kind: Literal["sf-check"] = "sf-check"
    decision: DecisionConfig
    shield: bool = True
    #: False: the shield leaves the planned presets alone (the defaults are then sf's); None: it checks every plan
    shield_presets: bool | None = None

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"shield_presets"})


@dataclass
class DecisionPlanner(PredictingPlanner):
    params: SocialForceParams
    decider: Decider
    shield_params: SocialForceParams | None = None
    name: str = "sf-check"
    batch_size: int = 256
    shield_presets: bool = True

    def choose(self, batch: ScenarioBatch, context: PlanningContext) -> tuple[np.ndarray, GatedChecks]:
        """(B,) each scenario's preset index and the checks it came from (``Decider.gated_checks``)."""
        gated = self.decider.gated_checks(batch, context.goals_xy_m, context.neighbours)
        return gated.rule(), gated

    def propose(self, batch: ScenarioBatch, context: PlanningContext) -> Proposals:
        chosen, gated = self.choose(batch, context)
        checks, consulted, risk = gated.checks, gated.consulted, gated.risk
        values = self.decider.presets.values[chosen]
        names = [self.decider.presets.names[k] for k in chosen]
        reasons = [decision_reason(self.decider, checks.row(i), names[i], bool(consulted[i]), float(risk[i]))
                   for i in range(len(batch))]
        from_values = SocialForceParams.from_matrix(
            np.concatenate([values[:, :6], np.full((len(batch), 1), self.params.r_col_m)], axis=1))
        info = decision_info(names, consulted, risk, np.zeros(len(batch)), reasons)
        # the checks planned and checked the chosen preset already: its plan and the adverse futures it fails
        rows = np.arange(len(batch))
        failed = checks.adverse_failed[rows, chosen]
        info["adverse_failed"] = np.asarray([",".join(checks.adverse_names[a] for a in np.flatnonzero(row))
                                             for row in failed], dtype=object)
        # the shield's preset alternatives come from these checks where every preset was checked (the same
        # inputs: not checked twice); it checks the other scenarios itself if their plan needs replacing
        extra = {PRESETS_PASS_ALL: checks.passes_all(), PRESETS_PROGRESS: checks.progress_m,
                 PRESETS_CHECKED: gated.complete, PROPOSED_XY: checks.xy_m[rows, chosen],
                 PROPOSED_VXY: checks.vxy_mps[rows, chosen], PROPOSED_GOALS: checks.goals_xy_m[rows, chosen]}
        return Proposals(params=from_values, lon_factor=values[:, 6], lane_factor=values[:, 7], info=info,
                         extra=extra)

    def simulate(self, batch: ScenarioBatch, context: PlanningContext, proposals: Proposals) -> PlanBatch:
        return simulate_and_shield(batch, context, proposals, self.shield_params, self.decider.thresholds,
                                   with_memories=False, decider=self.decider, shield_presets=self.shield_presets)
