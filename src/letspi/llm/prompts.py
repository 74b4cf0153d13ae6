"""Prompt rendering (paper Fig. 2) from the Jinja2 templates in ``letspi/prompts/*.j2``.

The system message is static per process and the user message carries what changes (scenario, memory
examples, safety report), so prefix caches hit; a reflection round continues the first exchange as a
multi-turn chat. ``render_physics_prompt``: memory collection (Fig. 2a); ``render_fast_prompt``: fast
inference (Fig. 2b).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Any, Final

import jinja2

from letspi.constants import DT_S, HORIZON_S
from letspi.llm.describe import ScenarioDescription, targeted_guidance
from letspi.llm.schema import FIELD_DOCS, FIELD_RANGES, RATIONALE_MAX_CHARS, WIRE_KEYS, PlannerReply, Variant
from letspi.llm.types import Message, message
from letspi.physics.social_force import LANE_LINE_SIGMA_M

#: Safety thresholds quoted in the prompts (paper §III-E: TTC < 1.5 s or distance < 2.0 m is unsafe).
TTC_MIN_S: Final = 1.5
DIST_MIN_M: Final = 2.0


@dataclass(frozen=True)
class MemoryExample:
    """One remembered, validated answer shown as a few-shot example: a one-line scenario ``summary`` and an
    optional safety ``outcome`` (``"min TTC 4.2 s, min gap 9.0 m"``)."""

    summary: str
    reply: PlannerReply
    outcome: str = ""

    def answer(self, variant: Variant) -> str:
        return json.dumps(self.reply.to_wire(variant), separators=(", ", ": "))


def _load_template(name: str) -> str:
    return resources.files("letspi").joinpath("prompts", name).read_text(encoding="utf-8")


@lru_cache(maxsize=1)
def prompt_environment() -> jinja2.Environment:
    """The Jinja2 environment reading package templates (strict: a missing variable is an error)."""
    return jinja2.Environment(
        loader=jinja2.FunctionLoader(_load_template),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=False,
        autoescape=False,  # plain-text prompts, not HTML
    )


def _fmt(x: float) -> str:
    return f"{x:g}"


def _static_context() -> dict[str, Any]:
    params = [
        {
            "key": WIRE_KEYS[name],
            "doc": FIELD_DOCS[name][1],
            "unit": FIELD_DOCS[name][0],
            "low": _fmt(lo),
            "high": _fmt(hi),
        }
        for name, (lo, hi) in FIELD_RANGES.items()
    ]
    return {
        "params": params,
        # wire key -> unit, for the equations in the templates (units from PARAM_UNITS, one source)
        "units": {WIRE_KEYS[name]: FIELD_DOCS[name][0] for name in FIELD_RANGES},
        "lane_sigma_m": _fmt(LANE_LINE_SIGMA_M),
        "horizon_s": _fmt(HORIZON_S),
        "dt_s": _fmt(DT_S),
        "ttc_min_s": _fmt(TTC_MIN_S),
        "dist_min_m": _fmt(DIST_MIN_M),
        "rationale_max": RATIONALE_MAX_CHARS,
    }


def _render(name: str, **context: Any) -> str:
    return prompt_environment().get_template(name).render(**context).strip()


@lru_cache(maxsize=2)
def system_prompt(variant: Variant = "physics") -> str:
    """The static system message of a prompt variant (identical on every call: prefix cache)."""
    return _render("physics_system.j2" if variant == "physics" else "fast_system.j2", **_static_context())


def _memories(memories: Sequence[MemoryExample], variant: Variant) -> list[dict[str, str]]:
    return [{"summary": m.summary, "outcome": m.outcome, "answer": m.answer(variant)} for m in memories]


def render_physics_prompt(
    scenario_description: ScenarioDescription,
    *,
    memories: Sequence[MemoryExample] = (),
    safety_report: str | None = None,
    previous_reply: str | None = None,
) -> list[Message]:
    """Messages of the physics-informed prompt. With ``safety_report``, a reflection round: a follow-up turn
    after ``previous_reply`` (the model's raw text) if given, else appended to the user message."""
    scenario_text = scenario_description.to_text(detail="full")
    mems = _memories(memories, "physics")
    system = message("system", system_prompt("physics"))
    if safety_report is not None and previous_reply is not None:
        first = _render("physics_user.j2", scenario_text=scenario_text, memories=mems, safety_report=None)
        return [
            system,
            message("user", first),
            message("assistant", previous_reply),
            message("user", _render("refinement.j2", safety_report=safety_report)),
        ]
    user = _render("physics_user.j2", scenario_text=scenario_text, memories=mems, safety_report=safety_report)
    return [system, message("user", user)]


def render_fast_prompt(
    scenario_description: ScenarioDescription,
    *,
    memories: Sequence[MemoryExample] = (),
    guidance: Sequence[str] | None = None,
) -> list[Message]:
    """Messages of the fast prompt (fast-inference phase). ``guidance`` defaults to
    ``targeted_guidance(scenario_description)``."""
    hints = list(guidance) if guidance is not None else targeted_guidance(scenario_description)
    user = _render(
        "fast_user.j2",
        scenario_text=scenario_description.to_text(detail="brief"),
        memories=_memories(memories, "fast"),
        guidance=hints,
    )
    return [message("system", system_prompt("fast")), message("user", user)]
