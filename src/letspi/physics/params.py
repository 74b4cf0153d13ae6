"""Social force parameters: one scenario (``SocialForceParams``) and a batch (``SocialForceParamsBatch``).

Units (unit mass, so forces are accelerations):

==============  ======  ==================================================================
name            unit    meaning
==============  ======  ==================================================================
tau_s           s       relaxation time of the goal attraction (Eq. 4)
k_np            m/s^2   repulsion from a preceding vehicle at zero gap (Eq. 6)
k_nf            m/s^2   repulsion from a following vehicle at zero gap
k_nl            m/s^2   repulsion from a lateral (adjacent-lane) vehicle at zero gap
k_boundary      m^3/s^2 strength of the road-edge potential ``k * 0.5 / d^2`` (Eq. 7)
k_cline         m^2/s^2 height of the lane-line potential ``k * exp(-d^2 / (2 sigma^2))``;
                        its peak force is ``0.61 * k / sigma`` = ``0.50 * k`` m/s^2 (sigma 1.22 m)
r_col_m         m       decay length of the neighbour repulsion ``k * exp(-d / r_col)``
==============  ======  ==================================================================

``PARAM_RANGES`` are hard physical limits (what LLM output is clamped to); ``TYPICAL_RANGES`` are the
starting ranges from REFERENCE §4 (guidance for prompts, not limits).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Final

import numpy as np

PARAM_NAMES: Final = ("tau_s", "k_np", "k_nf", "k_nl", "k_boundary", "k_cline", "r_col_m")
"""Column order of the (B, 7) matrix form (``SocialForceParamsBatch.as_matrix``)."""

PARAM_INDEX: Final = {name: i for i, name in enumerate(PARAM_NAMES)}

PARAM_UNITS: Final = {
    "tau_s": "s",
    "k_np": "m/s^2",
    "k_nf": "m/s^2",
    "k_nl": "m/s^2",
    "k_boundary": "m^3/s^2",
    "k_cline": "m^2/s^2",
    "r_col_m": "m",
}

PARAM_RANGES: Final = {
    # tau below ~0.3 s makes the goal term a bang-bang controller at 25 Hz; above 3 s it barely steers.
    "tau_s": (0.3, 3.0),
    # zero is allowed (switches a term off); upper limits are a few times the typical values.
    "k_np": (0.0, 60.0),
    "k_nf": (0.0, 20.0),
    "k_nl": (0.0, 5.0),
    "k_boundary": (0.0, 5.0),
    "k_cline": (0.0, 3.0),
    # shorter than a car length the repulsion acts only at contact; longer than ~20 m it brakes for everything.
    "r_col_m": (2.0, 20.0),
}

TYPICAL_RANGES: Final = {
    "tau_s": (0.5, 2.0),
    "k_np": (15.0, 30.0),
    "k_nf": (1.5, 9.0),
    "k_nl": (0.2, 1.0),
    "k_boundary": (0.5, 2.0),
    "k_cline": (0.3, 1.0),
    "r_col_m": (5.0, 15.0),
}


@dataclass(frozen=True)
class SocialForceParams:
    """Parameters of one social force rollout (units in the module docstring)."""

    tau_s: float = 1.0
    k_np: float = 25.0
    k_nf: float = 5.0
    k_nl: float = 0.5
    k_boundary: float = 1.0
    k_cline: float = 0.5
    r_col_m: float = 10.0

    def clamped(self) -> SocialForceParams:
        """A copy with every value clamped into ``PARAM_RANGES`` (non-finite -> default)."""
        default = SocialForceParams()
        out = {}
        for name in PARAM_NAMES:
            value = float(getattr(self, name))
            if not np.isfinite(value):
                value = float(getattr(default, name))
            lo, hi = PARAM_RANGES[name]
            out[name] = min(max(value, lo), hi)
        return SocialForceParams(**out)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def as_array(self) -> np.ndarray:
        """The values in ``PARAM_NAMES`` order, (7,) float64."""
        return np.array([getattr(self, name) for name in PARAM_NAMES], dtype=np.float64)

    @classmethod
    def from_mapping(cls, values: Mapping[str, float]) -> SocialForceParams:
        """From a mapping with (a subset of) the parameter names; missing ones take defaults."""
        unknown = set(values) - set(PARAM_NAMES)
        if unknown:
            raise KeyError(f"unknown social force parameters: {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in values.items()})


DEFAULT_PARAMS: Final = SocialForceParams()


@dataclass(frozen=True)
class SocialForceParamsBatch:
    """One parameter set per scenario: every field is a float64 array of shape (B,)."""

    tau_s: np.ndarray
    k_np: np.ndarray
    k_nf: np.ndarray
    k_nl: np.ndarray
    k_boundary: np.ndarray
    k_cline: np.ndarray
    r_col_m: np.ndarray

    def __post_init__(self) -> None:
        shapes = {np.shape(getattr(self, f.name)) for f in fields(self)}
        if len(shapes) != 1 or len(next(iter(shapes))) != 1:
            raise ValueError(f"SocialForceParamsBatch fields must share one (B,) shape, got {shapes}")

    def __len__(self) -> int:
        return int(self.tau_s.shape[0])

    @classmethod
    def broadcast(cls, params: SocialForceParams, n: int) -> SocialForceParamsBatch:
        """The same parameters for ``n`` scenarios."""
        return cls(**{name: np.full(n, float(getattr(params, name))) for name in PARAM_NAMES})

    @classmethod
    def stack(cls, params: Sequence[SocialForceParams]) -> SocialForceParamsBatch:
        """One row per element of ``params``."""
        return cls(
            **{name: np.array([getattr(p, name) for p in params], dtype=np.float64) for name in PARAM_NAMES}
        )

    @classmethod
    def from_matrix(cls, matrix: np.ndarray) -> SocialForceParamsBatch:
        """From a (B, 7) array with columns in ``PARAM_NAMES`` order."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != len(PARAM_NAMES):
            raise ValueError(f"expected (B, {len(PARAM_NAMES)}) parameters, got {m.shape}")
        return cls(**{name: m[:, i].copy() for i, name in enumerate(PARAM_NAMES)})

    def as_matrix(self) -> np.ndarray:
        """(B, 7) float64, columns in ``PARAM_NAMES`` order."""
        return np.stack([np.asarray(getattr(self, name), dtype=np.float64) for name in PARAM_NAMES], axis=1)

    def clamped(self) -> SocialForceParamsBatch:
        """A copy clamped into ``PARAM_RANGES``; non-finite entries take the default value."""
        out = {}
        for name in PARAM_NAMES:
            v = np.asarray(getattr(self, name), dtype=np.float64)
            v = np.where(np.isfinite(v), v, float(getattr(DEFAULT_PARAMS, name)))
            lo, hi = PARAM_RANGES[name]
            out[name] = np.clip(v, lo, hi)
        return SocialForceParamsBatch(**out)

    def row(self, index: int) -> SocialForceParams:
        """The parameters of scenario ``index``."""
        return SocialForceParams(**{name: float(getattr(self, name)[index]) for name in PARAM_NAMES})


def as_params_batch(
    params: SocialForceParams | SocialForceParamsBatch | Sequence[SocialForceParams], n: int
) -> SocialForceParamsBatch:
    """Normalise any accepted parameter form to a batch of length ``n``."""
    if isinstance(params, SocialForceParams):
        return SocialForceParamsBatch.broadcast(params, n)
    if isinstance(params, SocialForceParamsBatch):
        batch = params
    else:
        batch = SocialForceParamsBatch.stack(list(params))
    if len(batch) != n:
        raise ValueError(f"got parameters for {len(batch)} scenarios, expected {n}")
    return batch
