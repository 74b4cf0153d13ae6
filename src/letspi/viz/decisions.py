"""The report's "Decisions" section: per deciding planner its decision shares, the share consulted, and up to ``n``
scenarios where it left the defaults (first where ``sf`` collided and it did not), each with its reason and checks
and its stored plan beside sf's."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.constants import N_FUTURE
from letspi.evaluation.results import load_planner_results
from letspi.planners.base import PlanBatch
from letspi.planners.decision import ADVERSE_FAILED, CONSULTED, DECISION, REASON, REFINEMENTS, RISK_SCORE
from letspi.planners.llm import SHIELDED
from letspi.planners.outputs import column
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import count_scenarios, load_scenarios
from letspi.viz.figure import plot_scenario


@dataclass
class DecisionExample:
    scenario_id: str
    caption: str
    image: str | None = None  # data URI
    note: str = ""


@dataclass
class DecisionSection:
    name: str
    anchor: str
    summary: str
    examples: list[DecisionExample] = field(default_factory=list)


def _plan(rec: pd.Series) -> PlanBatch:
    return PlanBatch(xy_m=np.asarray(rec["plan_xy_m"], np.float64).reshape(1, N_FUTURE, 2),
                     vxy_mps=np.asarray(rec["plan_vxy_mps"], np.float64).reshape(1, N_FUTURE, 2),
                     goals_xy_m=np.asarray(rec["plan_goal_xy_m"], np.float64).reshape(1, 2))


def _summary(frame: pd.DataFrame) -> str:
    counts = frame[column(DECISION)].astype(str).value_counts()
    shares = ", ".join(f"{k} {100 * v / len(frame):.1f} %" for k, v in counts.items())
    consulted = np.asarray(frame.get(column(CONSULTED), pd.Series(np.ones(len(frame)))), dtype=bool).mean()
    shielded = np.asarray(frame.get(column(SHIELDED), pd.Series(np.zeros(len(frame)))), dtype=np.float64).mean()
    return (f"{len(frame)} windows: {shares}; the model was consulted on {100 * consulted:.1f} %, the shield "
            f"replaced {100 * shielded:.1f} % of the plans.")


def _caption(rec: pd.Series, ref: pd.Series | None, reference: str) -> str:
    parts = [f"decision {rec[column(DECISION)]}", str(rec.get(column(REASON), "")) or "no reason recorded"]
    if rec.get(column(ADVERSE_FAILED)):
        parts.append(f"first proposal failed {rec[column(ADVERSE_FAILED)]}")
    if float(rec.get(column(REFINEMENTS), 0) or 0) > 0:
        parts.append(f"{int(rec[column(REFINEMENTS)])} refinement round(s)")
    if float(rec.get(column(SHIELDED), 0) or 0) > 0:
        parts.append("the shield replaced the plan")
    outcome = "collided" if bool(rec["collision"]) else "no contact"
    if ref is not None:
        outcome += f"; {reference}: {'collided' if bool(ref['collision']) else 'no contact'}"
    return "; ".join([*parts, outcome])


def decision_sections(eval_dir: Path, frames: Mapping[str, pd.DataFrame], scenarios_file: Path | None,
                      figure_uri: object, *, reference: str = "sf", n: int = 3) -> list[DecisionSection]:
    """The section of every deciding planner (``figure_uri``: figure -> data URI, the report's encoder)."""
    sections = []
    ref_rows = (load_planner_results(eval_dir, reference, with_plans=True).set_index("scenario_digest")
                if reference in frames else None)
    n_file = count_scenarios(scenarios_file) if scenarios_file is not None else 0
    for name, frame in frames.items():
        if column(DECISION) not in frame or name == reference or not len(frame):
            continue
        sec = DecisionSection(name=name, anchor=f"decisions-{abs(hash(name)) % 10**8}", summary=_summary(frame))
        mine = load_planner_results(eval_dir, name, with_plans=True)
        changed = mine[mine[column(DECISION)].astype(str) != "default"]
        if ref_rows is not None and len(changed):
            ref_collides = np.array([bool(ref_rows.loc[d, "collision"]) if d in ref_rows.index else False
                                     for d in changed["scenario_digest"]])
            fixed = ref_collides & ~np.asarray(changed["collision"], dtype=bool)
            risk = np.nan_to_num(np.asarray(changed.get(column(RISK_SCORE), 0.0), dtype=np.float64))
            changed = changed.iloc[np.lexsort((-risk, ~fixed))]
        for _, rec in changed.head(n).iterrows():
            digest = str(rec["scenario_digest"])
            ref: pd.Series | None = None
            if ref_rows is not None and digest in ref_rows.index:
                found = ref_rows.loc[digest]
                assert isinstance(found, pd.Series)  # digests are unique in stored results
                ref = found
            example = DecisionExample(str(rec["scenario_id"]), _caption(rec, ref, reference))
            pos = int(rec["row"])
            scene = load_scenarios(scenarios_file, [pos]) if scenarios_file is not None and pos < n_file else None
            if scene is None or str(scenario_digests(scene)[0]) != digest:
                example.note = "scenario not found unchanged in the scenarios file: no diagram"
            else:
                plans = {name: _plan(rec), **({reference: _plan(ref)} if ref is not None else {})}
                fig = plot_scenario(scene, 0, plans, title=f"{name} ({rec[column(DECISION)]}) beside {reference}: "
                                                           f"scenario {rec['scenario_id']}", width_in=13.0)
                example.image = figure_uri(fig)  # type: ignore[operator]
            sec.examples.append(example)
        sections.append(sec)
    return sections
