"""Social force parameters (``SocialForceParams``: one scenario or a batch, the same type); unit mass.

``tau_s`` [s]: relaxation time of the goal attraction; ``k_np``, ``k_nf``, ``k_nl`` [m/s²]: repulsion from a
preceding, following and adjacent-lane vehicle at zero gap; ``k_boundary`` [m³/s²]: road-edge potential
``k 0.5 / d²``; ``k_cline`` [m²/s²]: lane-line potential ``k exp(-d² / (2 sigma²))``; ``r_col_m`` [m]: decay length
of the neighbour repulsion ``k exp(-d / r_col)``. ``PARAM_RANGES`` are hard limits (LLM output is clamped to
them); ``TYPICAL_RANGES`` guide prompts and bound the ``sf`` fit, not limits.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, Final, TypeAlias

import numpy as np

PARAM_NAMES: Final = ("tau_s", "k_np", "k_nf", "k_nl", "k_boundary", "k_cline", "r_col_m")
"""Column order of the (B, 7) matrix form (``SocialForceParams.as_matrix``)."""

PARAM_INDEX: Final = {name: i for i, name in enumerate(PARAM_NAMES)}

PARAM_UNITS: Final = {"tau_s": "s", "k_np": "m/s^2", "k_nf": "m/s^2", "k_nl": "m/s^2", "k_boundary": "m^3/s^2",
                      "k_cline": "m^2/s^2", "r_col_m": "m"}

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


#: float (one parameter set) or a (B,) float64 array (a batch); ``Any``: arithmetic on either works the same
FloatOrArray: TypeAlias = Any


@dataclass(frozen=True, eq=False)
class SocialForceParams:
    """Social force parameters of one scenario or of a batch (units in the module docstring). Every field holds float64
    of one shape: ``()`` for one set (an ``np.float64``) or ``(B,)``. ``broadcast``, ``stack`` and ``from_matrix`` build
    batches, ``row`` takes one set out; equality compares values."""

    tau_s: FloatOrArray = 1.0
    k_np: FloatOrArray = 25.0
    k_nf: FloatOrArray = 5.0
    k_nl: FloatOrArray = 0.5
    k_boundary: FloatOrArray = 1.0
    k_cline: FloatOrArray = 0.5
    r_col_m: FloatOrArray = 10.0

    def __post_init__(self) -> None:
        values = {name: np.asarray(getattr(self, name), dtype=np.float64) for name in PARAM_NAMES}
        shapes = {v.shape for v in values.values()}
        if len(shapes) != 1 or len(next(iter(shapes))) > 1:
            raise ValueError(f"SocialForceParams fields must share one shape, () or (B,), got {sorted(shapes)}")
        for name, v in values.items():
            object.__setattr__(self, name, v[()] if v.ndim == 0 else v)  # v[()] is an np.float64

    # shape ---------------------------------------------------------------------------------------
    @property
    def is_batch(self) -> bool:
        """True for (B,) fields, False for one parameter set."""
        return np.ndim(self.tau_s) == 1

    def __len__(self) -> int:
        if not self.is_batch:
            raise TypeError("one parameter set has no length; use a batch (SocialForceParams.broadcast)")
        return int(np.shape(self.tau_s)[0])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SocialForceParams):
            return NotImplemented
        return self.is_batch == other.is_batch and np.array_equal(self.as_array(), other.as_array(), equal_nan=True)

    def __hash__(self) -> int:
        return hash(self.as_array().tobytes())

    def __repr__(self) -> str:
        inner = ", ".join(f"{n}={np.round(getattr(self, n), 4)!r}" for n in PARAM_NAMES)
        return f"SocialForceParams({inner})"

    # construction ----------------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, values: Mapping[str, float]) -> SocialForceParams:
        """One set from a mapping with (a subset of) the parameter names; missing ones take defaults."""
        unknown = set(values) - set(PARAM_NAMES)
        if unknown:
            raise KeyError(f"unknown social force parameters: {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in values.items()})

    def broadcast(self, n: int) -> SocialForceParams:
        """These (single) parameters repeated for ``n`` scenarios."""
        if self.is_batch:
            raise TypeError("broadcast takes one parameter set, got a batch")
        return SocialForceParams(**{name: np.full(n, float(getattr(self, name))) for name in PARAM_NAMES})

    @classmethod
    def stack(cls, params: Sequence[SocialForceParams]) -> SocialForceParams:
        """A batch with one row per (single) element of ``params``."""
        return cls(**{name: np.array([float(getattr(p, name)) for p in params], dtype=np.float64)
                      for name in PARAM_NAMES})

    @classmethod
    def from_matrix(cls, matrix: np.ndarray) -> SocialForceParams:
        """A batch from a (B, 7) array with columns in ``PARAM_NAMES`` order."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != len(PARAM_NAMES):
            raise ValueError(f"expected (B, {len(PARAM_NAMES)}) parameters, got {m.shape}")
        return cls(**{name: m[:, i].copy() for i, name in enumerate(PARAM_NAMES)})

    # views -------------------------------------------------------------------------------------------
    def as_array(self) -> np.ndarray:
        """Values in ``PARAM_NAMES`` order: (7,) for one set, (B, 7) for a batch (float64)."""
        return np.stack([np.asarray(getattr(self, name), dtype=np.float64) for name in PARAM_NAMES], axis=-1)

    def as_matrix(self) -> np.ndarray:
        """(B, 7) float64 (a single set gives (1, 7))."""
        return np.atleast_2d(self.as_array())

    def as_dict(self) -> dict[str, float]:
        """Name -> value of one parameter set."""
        if self.is_batch:
            raise TypeError("as_dict takes one parameter set; use row(i) on a batch")
        return {name: float(getattr(self, name)) for name in PARAM_NAMES}

    def row(self, index: int) -> SocialForceParams:
        """The parameters of scenario ``index`` of a batch."""
        return SocialForceParams(**{name: float(np.asarray(getattr(self, name))[index]) for name in PARAM_NAMES})

    def clamped(self) -> SocialForceParams:
        """A copy with every value clamped into ``PARAM_RANGES``; non-finite values take the default."""
        out = {}
        for name in PARAM_NAMES:
            v = np.asarray(getattr(self, name), dtype=np.float64)
            v = np.where(np.isfinite(v), v, _DEFAULTS[name])
            lo, hi = PARAM_RANGES[name]
            out[name] = np.clip(v, lo, hi)
        return SocialForceParams(**out)


_DEFAULTS: Final = {f.name: float(f.default) for f in fields(SocialForceParams)}  # type: ignore[arg-type]
DEFAULT_PARAMS: Final = SocialForceParams()


def as_params_batch(params: SocialForceParams | Sequence[SocialForceParams], n: int) -> SocialForceParams:
    """Normalise any accepted parameter form to a batch of length ``n``."""
    if isinstance(params, SocialForceParams):
        batch = params if params.is_batch else params.broadcast(n)
    else:
        batch = SocialForceParams.stack(list(params))
    if len(batch) != n:
        raise ValueError(f"got parameters for {len(batch)} scenarios, expected {n}")
    return batch
