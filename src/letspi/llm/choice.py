"""The choice prompt: the model picks one of a few checked options instead of writing eight numbers.

Per option (a preset, planned and checked by ``letspi.method.decide``) the prompt lists the checks its
plan failed and its progress; the reply is ``{"option": NAME}`` constrained to the option names, so a
call costs little more than the prompt's prefill. Forms, both ``[system, user]``: propose, and refine
(adds the rejected option and what its check found). ``parse_choice`` validates a reply.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Final

from letspi.llm.compact import compact_scene_text
from letspi.llm.describe import ScenarioDescription
from letspi.llm.parse import extract_json_object
from letspi.llm.prompts import _render, _static_context
from letspi.llm.types import Message, ReplyParseError, message

CHOICE_KEY: Final = "option"
#: nearest cars the choice prompt lists (fewer than the compact prompt's: the options carry the checks)
MAX_CARS: Final = 3


@dataclass(frozen=True)
class OptionLine:
    """One option as the prompt lists it: its name, the checks its plan failed ("predicted" and/or adverse
    future names; empty = passes all) and the plan's progress [m] over the horizon."""

    name: str
    failed: tuple[str, ...]
    progress_m: float

    def context(self) -> dict[str, str]:
        progress = f"{self.progress_m:.0f}" if math.isfinite(self.progress_m) else "-"
        return {"name": self.name, "failed": ", ".join(self.failed) or "none", "progress": progress}


@lru_cache(maxsize=1)
def choice_system_prompt() -> str:
    """The static system message (the checks, the futures, the reply format)."""
    return _render("choice_system.j2", **_static_context())


def risk_text(risk: float) -> str:
    """The risk line's value: a percentage, ``-`` when unknown."""
    return f"{100 * risk:.0f} %" if math.isfinite(risk) else "-"


def render_choice_prompt(
    desc: ScenarioDescription,
    options: Sequence[OptionLine],
    *,
    risk: float = float("nan"),
    rejected: str | None = None,
    report: str | None = None,
) -> list[Message]:
    """``[system, user]``: the scene, the risk gate's score that the defaults collide (``risk`` in [0, 1];
    no line when NaN) and the options; a refinement adds ``rejected`` and its ``report`` (both or neither)."""
    if (rejected is None) != (report is None):
        raise ValueError("a choice refinement prompt needs both the rejected option and its report")
    if not options:
        raise ValueError("a choice prompt needs at least one option")
    user = _render("choice_user.j2", scene=compact_scene_text(desc, max_neighbours=MAX_CARS),
                   options=[o.context() for o in options],
                   risk=risk_text(risk) if math.isfinite(risk) else "", rejected=rejected or "", report=report or "",
                   horizon_s=_static_context()["horizon_s"])
    return [message("system", choice_system_prompt()), message("user", user)]


def choice_check_text(failed: Sequence[str]) -> str:
    """The check line of a refinement: ``failed predicted, leader-brakes`` (or ``passed every check``)."""
    return f"failed {', '.join(failed)}" if failed else "passed every check"


def choice_json_schema(names: Sequence[str]) -> dict[str, Any]:
    """JSON schema of the reply: one key whose value is one of ``names`` (llama.cpp's grammar enforces it)."""
    return {"type": "object", "properties": {CHOICE_KEY: {"type": "string", "enum": list(names)}},
            "required": [CHOICE_KEY], "additionalProperties": False}


def choice_reply_text(name: str) -> str:
    """The reply as the model should write it (the training target)."""
    return f'{{"{CHOICE_KEY}": "{name}"}}'


def parse_choice(text: str, names: Sequence[str]) -> str:
    """The chosen option's name, or ``ReplyParseError`` (``no_json``, ``missing_keys``, ``bad_value``)."""
    obj = extract_json_object(text)
    if CHOICE_KEY not in obj:
        raise ReplyParseError("missing_keys", f"no {CHOICE_KEY!r} in the reply")
    value = obj[CHOICE_KEY]
    if not isinstance(value, str) or value not in names:
        raise ReplyParseError("bad_value", f"{CHOICE_KEY} {value!r} is not one of {', '.join(names)}")
    return value
