""""Did you mean": the known names closest to a mistyped one, for the one line an error prints."""

from __future__ import annotations

from collections.abc import Iterable
from difflib import get_close_matches


def did_you_mean(value: object, known: Iterable[str], n: int = 2) -> str:
    """``"; did you mean sf?"`` (the up to ``n`` known names closest to ``value``), or "" when none is close."""
    close = get_close_matches(str(value), list(known), n=n, cutoff=0.6)
    return f"; did you mean {' or '.join(close)}?" if close else ""


def unknown(what: str, value: object, known: Iterable[str]) -> str:
    """``unknown goal source 'learnd'; did you mean learned? (available: learned, kinematic, oracle)``."""
    names = list(known)
    return f"unknown {what} {value!r}{did_you_mean(value, names)} (available: {', '.join(names)})"
