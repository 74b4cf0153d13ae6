"""Where a command of ``letspi`` is defined: the one type a distribution needs to add commands."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CommandEntry:
    """Where a command is defined (``module``: its import path; ``attribute``: its function or its ``typer.Typer``
    of sub-commands) and its summary for ``letspi --help`` (one sentence, no period)."""

    module: str
    attribute: str
    summary: str
