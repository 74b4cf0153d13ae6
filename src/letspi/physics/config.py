"""The configurations of the physics building blocks the planners share: social force parameter values,
the goal source, a trained model directory."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import field_validator

from letspi.keyed import Config
from letspi.physics.params import PARAM_NAMES, SocialForceParams


class SfParamsConfig(Config):
    """Social force parameter values (one set, ``PARAM_NAMES`` -> value) and, cosmetically, their file."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"source"})

    values: dict[str, float]
    source: str = "shipped"

    @field_validator("values")
    @classmethod
    def _all_parameters(cls, values: dict[str, float]) -> dict[str, float]:
        if set(values) != set(PARAM_NAMES):
            raise ValueError(f"social force parameters must be exactly {PARAM_NAMES}, got {sorted(values)}")
        return {name: float(values[name]) for name in PARAM_NAMES}

    @classmethod
    def of(cls, params: SocialForceParams, source: str) -> SfParamsConfig:
        return cls(values=params.as_dict(), source=source)

    def params(self) -> SocialForceParams:
        return SocialForceParams(**self.values)


GoalSource = Literal["learned", "kinematic", "oracle", "mobil"]


class GoalsConfig(Config):
    """Where goals come from. ``learned`` carries the fingerprint of the weights it uses; when no
    weights are found it falls back to ``kinematic`` and says so (``fallback_reason``)."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_dir", "fallback_reason"})

    source: GoalSource = "learned"
    weights_sha256: str | None = None
    weights_dir: str | None = None
    fallback_reason: str | None = None

    @property
    def reads_future(self) -> bool:
        return self.source == "oracle"


class WeightsConfig(Config):
    """A trained model directory, identified by the fingerprint of its files."""

    cosmetic: ClassVar[frozenset[str]] = frozenset({"weights_dir"})

    weights_sha256: str
    weights_dir: str
