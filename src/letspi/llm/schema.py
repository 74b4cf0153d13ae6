"""The LLM's reply: six social-force parameters, two goal-adjustment factors, a rationale.

``LLM_PARAM_RANGES`` is ``letspi.physics.params.PARAM_RANGES`` (one table for what the LLM may say and what
the rollout accepts; ``r_col_m`` stays fixed). Replies use short JSON keys (``WIRE_KEYS``: output tokens
dominate latency). Variants: ``"physics"`` (rationale first, so a model reasons before the numbers) and
``"fast"`` (numbers only).
"""

from __future__ import annotations

from typing import Any, Final, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field

from letspi.physics.goals import NEUTRAL_LON_FACTOR
from letspi.physics.params import PARAM_RANGES, PARAM_UNITS, SocialForceParams

Variant = Literal["physics", "fast"]
VARIANTS: Final[tuple[Variant, ...]] = ("physics", "fast")

#: Social-force parameter ranges (name -> (low, high)); units in ``FIELD_UNITS`` (from ``PARAM_UNITS``).
LLM_PARAM_RANGES: Final[dict[str, tuple[float, float]]] = {
    name: PARAM_RANGES[name] for name in ("tau_s", "k_np", "k_nf", "k_nl", "k_boundary", "k_cline")
}
#: Goal-adjustment factor ranges (paper §III-E).
GOAL_FACTOR_RANGES: Final[dict[str, tuple[float, float]]] = {"lon_factor": (0.0, 1.0), "lane_factor": (-1.0, 1.0)}
#: Every numeric field of a reply with its range, in wire order.
FIELD_RANGES: Final[dict[str, tuple[float, float]]] = {**LLM_PARAM_RANGES, **GOAL_FACTOR_RANGES}
NUMERIC_FIELDS: Final[tuple[str, ...]] = tuple(FIELD_RANGES)

#: Canonical field name -> short JSON key used on the wire.
WIRE_KEYS: Final[dict[str, str]] = {
    "rationale": "why", "tau_s": "tau", "k_np": "k_np", "k_nf": "k_nf", "k_nl": "k_nl", "k_boundary": "k_bd",
    "k_cline": "k_cl", "lon_factor": "lon", "lane_factor": "lane",
}

#: Longest rationale the schema allows (characters); about 60 tokens.
RATIONALE_MAX_CHARS: Final = 240

#: Unit of every numeric field (from ``PARAM_UNITS``; ``-`` for the dimensionless goal factors).
FIELD_UNITS: Final[dict[str, str]] = {
    **{name: PARAM_UNITS[name] for name in LLM_PARAM_RANGES},
    **{name: "-" for name in GOAL_FACTOR_RANGES},
}

_FIELD_MEANINGS: Final[dict[str, str]] = {
    "tau_s": "relaxation time: how fast the ego adapts to its desired velocity (small = eager)",
    "k_np": "repulsion from the preceding vehicle (same lane, ahead)",
    "k_nf": "repulsion from the following vehicle (same lane, behind)",
    "k_nl": "repulsion from lateral vehicles (adjacent lanes)",
    "k_boundary": "strength of the road-edge potential (edges are not crossable)",
    "k_cline": "height of the lane-line potential (keeps the ego centred in its lane)",
    "lon_factor": "goal distance: 0 = 20% farther, 0.4 = unchanged, 1 = 30% shorter",
    "lane_factor": "goal lane shift: -1 = one lane left, 0 = keep, +1 = one lane right",
}

#: Unit and one-line meaning of every numeric field, used by the prompts.
FIELD_DOCS: Final[dict[str, tuple[str, str]]] = {
    name: (FIELD_UNITS[name], _FIELD_MEANINGS[name]) for name in FIELD_RANGES
}


def _param_field(name: str, wire: str) -> Any:
    """A reply field accepting the canonical name or the wire key, bounded by ``PARAM_RANGES``."""
    low, high = PARAM_RANGES[name]
    return Field(validation_alias=AliasChoices(name, wire), serialization_alias=wire, ge=low, le=high)


class PlannerReply(BaseModel):
    """A validated reply, always within range (from raw text: ``parse_reply``). Populate by canonical name or
    wire key; ``model_dump(by_alias=True)`` gives the wire keys."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    tau_s: float = _param_field("tau_s", "tau")
    k_np: float = _param_field("k_np", "k_np")
    k_nf: float = _param_field("k_nf", "k_nf")
    k_nl: float = _param_field("k_nl", "k_nl")
    k_boundary: float = _param_field("k_boundary", "k_bd")
    k_cline: float = _param_field("k_cline", "k_cl")
    lon_factor: float = Field(validation_alias=AliasChoices("lon_factor", "lon"), serialization_alias="lon", ge=0.0,
                              le=1.0)
    lane_factor: float = Field(validation_alias=AliasChoices("lane_factor", "lane"), serialization_alias="lane",
                               ge=-1.0, le=1.0)
    rationale: str = Field(default="", validation_alias=AliasChoices("rationale", "why"), serialization_alias="why")

    def params(self) -> dict[str, float]:
        """The six social-force parameters (canonical names)."""
        return {k: float(getattr(self, k)) for k in LLM_PARAM_RANGES}

    def goal_factors(self) -> tuple[float, float]:
        """``(lon_factor, lane_factor)``."""
        return self.lon_factor, self.lane_factor

    def to_wire(self, variant: Variant = "physics", decimals: int = 2) -> dict[str, Any]:
        """The reply as the model should write it (short keys, rounded); used for few-shot examples."""
        out: dict[str, Any] = {}
        if variant == "physics":
            out[WIRE_KEYS["rationale"]] = self.rationale[:RATIONALE_MAX_CHARS]
        for name in NUMERIC_FIELDS:
            out[WIRE_KEYS[name]] = round(float(getattr(self, name)), decimals)
        return out


#: Library fallback when every attempt failed: parameters inside ``TYPICAL_RANGES``
#: (``letspi.physics.params``), neutral goal. letspi's planners pass the fitted ``sf`` parameters instead
#: (``fallback_reply_from_params``), so a failed call plans like the ``sf`` baseline.
DEFAULT_REPLY: Final = PlannerReply(
    tau_s=1.0, k_np=25.0, k_nf=5.0, k_nl=0.5, k_boundary=1.0, k_cline=0.5, lon_factor=NEUTRAL_LON_FACTOR,
    lane_factor=0.0, rationale="default parameters (fallback)",
)


def reply_json_schema(variant: Variant = "physics") -> dict[str, Any]:
    """JSON schema of the wire reply, for constrained decoding. Property order is generation order;
    ``minimum``/``maximum`` are advisory (llama.cpp's grammar ignores them; ``parse_reply`` clamps)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown reply variant {variant!r}; expected one of {VARIANTS}")
    props: dict[str, Any] = {}
    if variant == "physics":
        props[WIRE_KEYS["rationale"]] = {"type": "string", "maxLength": RATIONALE_MAX_CHARS}
    for name, (lo, hi) in FIELD_RANGES.items():
        props[WIRE_KEYS[name]] = {"type": "number", "minimum": lo, "maximum": hi}
    return {"type": "object", "properties": props, "required": list(props), "additionalProperties": False}


def fallback_reply_from_params(params: SocialForceParams,
                               rationale: str = "fallback: fitted sf parameters") -> PlannerReply:
    """A neutral-goal reply carrying ``params`` (letspi's fallback when the LLM gives no valid answer)."""
    values = {k: v for k, v in params.as_dict().items() if k in LLM_PARAM_RANGES}
    return PlannerReply(**values, lon_factor=NEUTRAL_LON_FACTOR, lane_factor=0.0, rationale=rationale)
