"""The prompt fingerprint: SHA-256 of the prompt templates and of the prompts as rendered for fixed scenes.

It enters the key of every configuration that asks a model (docs/llm.md). ``FINGERPRINT_SCENES`` are rendered
through the real code by every style in ``PROMPT_STYLES`` and every template branch; a style without a
renderer in ``STYLE_SAMPLES`` makes the fingerprint raise. Text written by higher layers comes in as
``extra_texts`` (``letspi.method.prompt_samples``).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import replace
from importlib import resources
from typing import Final

import numpy as np

from letspi.llm import choice, client, compact, prompts
from letspi.llm.compact import PROMPT_STYLES, PromptStyle
from letspi.llm.describe import ScenarioDescription, describe_scenario
from letspi.llm.prompts import MemoryExample
from letspi.llm.schema import VARIANTS, PlannerReply
from letspi.llm.types import Message, ReplyParseError
from letspi.scenario.build import LANE_WIDTH_M, VehicleSpec, straight_road_scenario
from letspi.scenario.types import VEHICLE_CLASS_TRUCK, ScenarioBatch

#: Rendered prompts by sample name: a list of messages, or one text (a summary line, a corrective message).
Samples = dict[str, list[Message] | str]


def _empty_road() -> tuple[ScenarioBatch, tuple[float, float]]:
    """Two lanes, the ego alone in the right one at a posted limit; the goal straight ahead."""
    batch = straight_road_scenario(ego_speed_mps=25.0, n_lanes=2, ego_lane_index=0, scenario_id="fp-empty")
    return replace(batch, speed_limit_mps=np.array([33.0], dtype=np.float32)), (125.0, 0.0)


def _busy_road() -> tuple[ScenarioBatch, tuple[float, float]]:
    """Three lanes, the ego braking in the middle, closing leader and follower, traffic on both sides."""
    nbrs = (
        VehicleSpec(x0_m=22.0, speed_mps=24.0),  # closing leader
        VehicleSpec(x0_m=-15.0, speed_mps=34.0),  # closing follower
        VehicleSpec(x0_m=3.0, speed_mps=29.0, lane_offset=1),  # beside, left
        VehicleSpec(x0_m=31.0, speed_mps=27.0, lane_offset=-1, vehicle_class=VEHICLE_CLASS_TRUCK,
                    length_m=12.0, width_m=2.5),
        VehicleSpec(x0_m=-26.0, speed_mps=31.0, lane_offset=-1, visible_from_index=60),  # short history
        VehicleSpec(x0_m=48.0, speed_mps=30.0, lane_offset=1, accel_mps2=-0.8),
    )
    batch = straight_road_scenario(ego_speed_mps=30.0, ego_accel_mps2=-1.2, neighbours=nbrs, n_lanes=3,
                                   ego_lane_index=1, scenario_id="fp-busy")
    return batch, (140.0, LANE_WIDTH_M)


def _crowded_road() -> tuple[ScenarioBatch, tuple[float, float]]:
    """Four lanes, the ego on the left, every neighbour slot filled (overlapping, far lanes, a leader pulling
    away); the goal one lane to the right."""
    nbrs = (
        VehicleSpec(x0_m=2.0, speed_mps=20.0),  # overlapping boxes in the ego lane: TTC 0
        VehicleSpec(x0_m=40.0, speed_mps=26.0),  # leader pulling away: not closing
        VehicleSpec(x0_m=-9.0, speed_mps=19.0, lane_offset=-1),
        VehicleSpec(x0_m=12.0, speed_mps=18.0, lane_offset=-2),
        VehicleSpec(x0_m=-30.0, speed_mps=22.0, lane_offset=-3, vehicle_class=VEHICLE_CLASS_TRUCK,
                    length_m=16.0, width_m=2.5),
        VehicleSpec(x0_m=60.0, speed_mps=21.0, lane_offset=-2),
        VehicleSpec(x0_m=-55.0, speed_mps=23.0),
        VehicleSpec(x0_m=75.0, speed_mps=17.0, lane_offset=-3),
    )
    batch = straight_road_scenario(ego_speed_mps=21.0, ego_accel_mps2=0.6, neighbours=nbrs, n_lanes=4,
                                   ego_lane_index=3, scenario_id="fp-crowded")
    return batch, (95.0, -LANE_WIDTH_M)


#: The fixed scenes: name -> (scenario batch of one, predicted goal (x, y) in m, ego frame).
FINGERPRINT_SCENES: Final[dict[str, Callable[[], tuple[ScenarioBatch, tuple[float, float]]]]] = {
    "empty": _empty_road,
    "busy": _busy_road,
    "crowded": _crowded_road,
}

#: A reply as a model gives it (the previous answer of a reflection round, a few-shot answer).
_REPLY: Final = PlannerReply(tau_s=1.6, k_np=12.0, k_nf=8.5, k_nl=2.25, k_boundary=1.5, k_cline=0.8,
                             lon_factor=0.55, lane_factor=-0.5, rationale="leader closing: brake early")
#: A safety report as the reflection module writes it (its real text comes in through ``extra_texts``).
_REPORT: Final = "Safety analysis of the planned 5.0 s trajectory: UNSAFE, 1 violation(s).\n- front TTC 1.1 s."
_CHECK: Final = {"min_ttc_s": 1.12, "min_rear_ttc_s": float("inf"), "min_path_gap_m": 3.4, "collision": 1.0}


def _memories(desc: ScenarioDescription) -> list[MemoryExample]:
    return [MemoryExample(desc.summary_line(), _REPLY, outcome="min TTC 4.2 s, min in-path gap 9.0 m"),
            MemoryExample("3 lanes, no leader", _REPLY)]


def _paper_samples(desc: ScenarioDescription) -> Samples:
    mems = _memories(desc)
    return {
        "physics": prompts.render_physics_prompt(desc),
        "physics+memories": prompts.render_physics_prompt(desc, memories=mems),
        "physics+report": prompts.render_physics_prompt(desc, safety_report=_REPORT),
        "physics+memories+turn": prompts.render_physics_prompt(
            desc, memories=mems, safety_report=_REPORT, previous_reply=compact.compact_reply_text(_REPLY)),
        "fast": prompts.render_fast_prompt(desc),
        "fast+memories": prompts.render_fast_prompt(desc, memories=mems),
        "fast+no-guidance": prompts.render_fast_prompt(desc, memories=mems, guidance=[]),
    }


def _compact_samples(desc: ScenarioDescription) -> Samples:
    return {
        "compact": compact.render_compact_prompt(desc),
        "compact+refine": compact.render_compact_prompt(
            desc, rejected=_REPLY, report=compact.compact_report_text(_CHECK, ["front_ttc", "in_path_gap"])),
        "compact+refine-values": compact.render_compact_prompt(
            desc, rejected=_REPLY.model_dump(), report=compact.compact_report_text({}, [])),
    }


def _choice_samples(desc: ScenarioDescription) -> Samples:
    lines = [choice.OptionLine("default", ("leader-brakes",), 141.2), choice.OptionLine("keep-gap", (), 131.0),
             choice.OptionLine("lane-left", ("predicted", "cut-in", "follower-keeps"), float("nan"))]
    return {
        "choice": choice.render_choice_prompt(desc, lines),
        "choice+risk": choice.render_choice_prompt(desc, lines, risk=0.234),
        "choice+refine": choice.render_choice_prompt(desc, lines, risk=0.05, rejected="default",
                                                     report=choice.choice_check_text(["predicted", "leader-brakes"])),
    }


#: Each prompt style's renderer of one scene; ``prompt_samples`` refuses a style missing here.
STYLE_SAMPLES: Final[dict[PromptStyle, Callable[[ScenarioDescription], Samples]]] = {
    "paper": _paper_samples,
    "compact": _compact_samples,
    "choice": _choice_samples,
}


def prompt_samples() -> Samples:
    """Every sample prompt, by name (``<scene>/<style>/<form>``, then the scene-free texts)."""
    missing = [s for s in PROMPT_STYLES if s not in STYLE_SAMPLES]
    if missing:
        raise RuntimeError(f"prompt style(s) {', '.join(missing)} have no fingerprint samples: add a renderer "
                           "to letspi.llm.fingerprint.STYLE_SAMPLES")
    out: Samples = {}
    for scene, build in FINGERPRINT_SCENES.items():
        batch, goal_xy = build()
        desc = describe_scenario(batch, goal_xy)
        out[f"{scene}/summary"] = desc.summary_line()
        for style in PROMPT_STYLES:
            out.update({f"{scene}/{style}/{form}": msgs for form, msgs in STYLE_SAMPLES[style](desc).items()})
    error = ReplyParseError("missing_keys", "no k_nl")
    for variant in VARIANTS:
        out[f"corrective/{variant}"] = client.corrective_message(error, variant)
    out["corrective/choice"] = client.choice_corrective_message(error, ("default", "keep-gap"))
    return out


def template_files() -> dict[str, bytes]:
    """Every prompt template (``letspi/prompts/*.j2``) by name, in name order."""
    folder = resources.files("letspi").joinpath("prompts")
    return {t.name: t.read_bytes() for t in sorted(folder.iterdir(), key=lambda t: t.name) if t.name.endswith(".j2")}


def prompt_fingerprint(extra_texts: Mapping[str, str] | None = None) -> str:
    """SHA-256 (hex) of the templates, ``prompt_samples()`` and ``extra_texts`` (higher layers' prompt text)."""
    h = hashlib.sha256()
    for name, data in template_files().items():
        h.update(name.encode() + b"\0" + data + b"\0")
    body = {"samples": prompt_samples(), "extra": dict(sorted((extra_texts or {}).items()))}
    h.update(json.dumps(body, sort_keys=True, ensure_ascii=False).encode())
    return h.hexdigest()
