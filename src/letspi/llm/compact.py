"""The compact prompt: the scene in a few lines, no few-shot examples, a numbers-only reply.

For the fine-tuned embedded model, which learned from labels instead of examples: a short prompt (prefill
is most of the latency) and the ``"fast"`` wire format with few decimals. Two forms, both
``[system, user]``: propose (the scene), and refine (adds the rejected answer and its safety-check facts).
Training (``letspi_train.finetune.data``) and planning render both here, so the model sees what it was trained on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from functools import lru_cache
from typing import Any, Final, Literal

from letspi.llm.describe import ScenarioDescription
from letspi.llm.prompts import _render, _static_context
from letspi.llm.schema import NUMERIC_FIELDS, WIRE_KEYS, PlannerReply
from letspi.llm.types import Message, message

#: How planners prompt a model: ``paper`` (physics prompt + fast prompt with few-shot memories, Fig. 2),
#: ``compact`` (this module: the scene in a few lines, the eight numbers as the reply) or ``choice``
#: (``letspi.llm.choice``: the model picks one of the checked presets).
PromptStyle = Literal["paper", "compact", "choice"]
PROMPT_STYLES: Final[tuple[PromptStyle, ...]] = ("paper", "compact", "choice")

#: Nearest neighbours listed (sorted by distance); the rest are left out to bound the prompt.
MAX_NEIGHBOURS: Final = 6
#: Same-lane TTCs above this are shown as ``-`` (no conflict within the horizon's reach).
MAX_TTC_SHOWN_S: Final = 20.0
#: Decimals of each field in a compact reply: SmolLM2 spends one token per digit, and output tokens
#: are most of the latency; 1 m/s^2 on the large repulsion gains is below what changes a plan.
REPLY_DECIMALS: Final[dict[str, int]] = {
    "tau_s": 1, "k_np": 0, "k_nf": 0, "k_nl": 1, "k_boundary": 1, "k_cline": 1, "lon_factor": 2, "lane_factor": 1,
}


def _f(v: float, decimals: int = 1) -> str:
    s = f"{v:.{decimals}f}"
    return s[1:] if s.startswith("-") and float(s) == 0.0 else s


@lru_cache(maxsize=1)
def compact_system_prompt() -> str:
    """The static system message (field ranges and meanings, safety thresholds)."""
    return _render("compact_system.j2", **_static_context())


def _lane_position(desc: ScenarioDescription) -> tuple[int, int]:
    """(ego lane counted from the left, 1-based; number of lanes)."""
    ids_l2r = [ln.lane_id for ln in reversed(desc.lanes)]
    k = ids_l2r.index(desc.ego_lane) + 1 if desc.ego_lane in ids_l2r else 0
    return k, len(ids_l2r)


def _goal_lane_text(desc: ScenarioDescription) -> str:
    ids_l2r = [ln.lane_id for ln in reversed(desc.lanes)]
    if desc.goal_lane not in ids_l2r or desc.ego_lane not in ids_l2r:
        return "lane unknown"
    shift = ids_l2r.index(desc.goal_lane) - ids_l2r.index(desc.ego_lane)
    if shift == 0:
        return "same lane"
    return f"{abs(shift)} lane{'s' if abs(shift) > 1 else ''} {'right' if shift > 0 else 'left'}"


def compact_scene_text(desc: ScenarioDescription, *, max_neighbours: int = MAX_NEIGHBOURS) -> str:
    """The scene in a few lines (ego frame: x along travel, y left; m, m/s, s)."""
    k, n = _lane_position(desc)
    left = "yes" if desc.lane_left_of(desc.ego_lane) is not None else "no"
    right = "yes" if desc.lane_right_of(desc.ego_lane) is not None else "no"
    limit = "none" if desc.speed_limit_mps is None else f"{_f(desc.speed_limit_mps)} m/s"
    lines = [
        f"Road: {n} lanes, ego lane {k} from left, left lane {left}, right lane {right}, limit {limit}",
        f"Ego: speed {_f(desc.ego_speed)}, acc {_f(desc.ego_ax)}, lateral {_f(desc.ego_vy)}.",
    ]
    shown = desc.neighbours[:max_neighbours]
    lines.append(f"Cars {len(shown)} of {len(desc.neighbours)} (dx dy m, rel speed m/s):")
    if not shown:
        lines.append("none")
    for nb in shown:  # nearest first; metres as integers (one token per digit)
        if nb.relation in ("ahead", "behind", "alongside"):  # same lane: dy ~ 0, the gap and TTC matter
            ttc = _f(nb.ttc_s) if nb.ttc_s is not None and nb.ttc_s <= MAX_TTC_SHOWN_S else "-"
            lines.append(f"{nb.relation} dx {_f(nb.x, 0)} rel {_f(nb.rel_vx)} gap {_f(nb.gap_m, 0)} TTC {ttc}")
        else:
            lines.append(f"{nb.relation} dx {_f(nb.x, 0)} dy {_f(nb.y, 0)} rel {_f(nb.rel_vx)}")
    lines.append(f"Goal at {_f(desc.horizon_s, 0)} s: dx {_f(desc.goal_x, 0)} dy {_f(desc.goal_y, 0)}, "
                 f"{_goal_lane_text(desc)}.")
    return "\n".join(lines)


def compact_reply_text(values: Mapping[str, float] | PlannerReply) -> str:
    """The numbers-only wire reply (``WIRE_KEYS``, ``REPLY_DECIMALS``) of canonical field values, in a
    layout llama.cpp's JSON-schema grammar accepts (the training target)."""
    get = (lambda k: getattr(values, k)) if isinstance(values, PlannerReply) else values.__getitem__
    out: dict[str, float | int] = {}
    for name in NUMERIC_FIELDS:
        v = round(float(get(name)), REPLY_DECIMALS[name])
        out[WIRE_KEYS[name]] = int(v) if REPLY_DECIMALS[name] == 0 else (0.0 if v == 0 else v)  # no "-0.0"
    return json.dumps(out, separators=(", ", ": "))


def compact_values_text(values: Mapping[str, float] | PlannerReply) -> str:
    """``tau 1.7 k_np 11 ...``: a rejected answer in few tokens (wire keys, ``REPLY_DECIMALS``)."""
    wire = json.loads(compact_reply_text(values))
    return " ".join(f"{k} {v}" for k, v in wire.items())


def _num(value: Any) -> str:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return "-"
    return _f(x) if math.isfinite(x) else "-"


def compact_report_text(metrics: Mapping[str, Any], violations: Sequence[str]) -> str:
    """One line of safety-check facts from ``metrics`` (min_ttc_s, min_rear_ttc_s [s], min_path_gap_m [m]:
    ``-`` when None or non-finite; collision) and the failed checks' names ``violations``."""
    contact = "yes" if bool(metrics.get("collision")) else "no"
    failed = ", ".join(dict.fromkeys(violations)) or "none"
    return (
        f"front TTC {_num(metrics.get('min_ttc_s'))}, rear TTC {_num(metrics.get('min_rear_ttc_s'))}, "
        f"gap {_num(metrics.get('min_path_gap_m'))}, contact {contact}; failed {failed}."
    )


def render_compact_prompt(
    desc: ScenarioDescription,
    *,
    rejected: Mapping[str, float] | PlannerReply | None = None,
    report: str | None = None,
) -> list[Message]:
    """``[system, user]``: the scene, and for a refinement the rejected answer and its check
    (``compact_report_text``); both or neither of ``rejected`` and ``report``."""
    if (rejected is None) != (report is None):
        raise ValueError("a compact refinement prompt needs both the rejected answer and its report")
    user = _render(
        "compact_user.j2",
        scene=compact_scene_text(desc),
        rejected=compact_values_text(rejected) if rejected is not None else "",
        report=report or "",
    )
    return [message("system", compact_system_prompt()), message("user", user)]
