"""Fitted social-force parameters on disk (a ``FittedFile`` with field ``params``; ``--sf-params FILE``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from letspi.physics.params import PARAM_NAMES, SocialForceParams
from letspi.planners.fitted import FittedFile

SHIPPED_FILE = "sf_params.json"
SF_PARAMS_FILE = FittedFile("params", SHIPPED_FILE, "SF parameter file", "letspi fit sf")


def _params(values: Mapping[str, object]) -> SocialForceParams:
    missing = [n for n in PARAM_NAMES if n not in values]
    if missing:
        raise ValueError(f"missing parameter(s) {missing}")
    return SocialForceParams.from_mapping({n: float(values[n]) for n in PARAM_NAMES})  # type: ignore[arg-type]


def load_sf_params(path: Path | None = None) -> tuple[SocialForceParams, dict[str, object]]:
    """Parameters and the whole record from ``path`` (default: the shipped fit)."""
    return SF_PARAMS_FILE.load(path, _params)


def save_sf_params(path: Path, params: SocialForceParams, provenance: dict[str, object],
                   objective: dict[str, object]) -> Path:
    """Write a fit atomically (``letspi.planners.fitted``)."""
    return SF_PARAMS_FILE.save(path, params.as_dict(), provenance, objective)
