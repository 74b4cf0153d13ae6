"""Locate the SUMO executables shipped with the ``eclipse-sumo`` wheel."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import sumo  # the eclipse-sumo wheel's package (a dependency): its SUMO_HOME


def sumo_home() -> Path:
    """SUMO_HOME of the installed ``eclipse-sumo`` wheel (importing ``sumo`` also sets the env var)."""
    return Path(sumo.SUMO_HOME)


def sumo_binary(name: str) -> str:
    """Absolute path of a SUMO tool (``sumo``, ``netconvert``), preferring the wheel's own copy."""
    candidate = sumo_home() / "bin" / name
    if candidate.is_file() and os.access(candidate, os.X_OK):
        return str(candidate)
    found = shutil.which(name)
    if found is None:
        raise RuntimeError(f"SUMO executable {name!r} not found")
    return found
