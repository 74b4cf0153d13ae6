"""What runs before a command line is parsed: the debug switch, and planner kinds named by import path.

A kind given as ``--planner pkg.mod:NAME`` (or ``LABEL=pkg.mod:NAME``) is loaded before the command's
options are parsed, so that its options are flags of the command as an installed kind's are;
``--planner-path DIR`` adds a directory to import it from (the current directory is searched too,
``letspi.assembly.planner_table.load_kind``). Nothing here imports more than the standard library
unless the command line names such a kind.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

#: set to 1 (or ``letspi --debug``) for tracebacks instead of one-line errors
DEBUG_ENV = "LETSPI_DEBUG"
PLANNER_FLAG = "--planner"
PLANNER_PATH_FLAG = "--planner-path"


def debug_enabled() -> bool:
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


def flag_values(args: Sequence[str], flag: str) -> list[str]:
    """The values given to ``flag`` in ``args`` (``--flag VALUE`` or ``--flag=VALUE``), in order."""
    values = []
    for i, arg in enumerate(args):
        if arg == "--":
            break
        if arg == flag and i + 1 < len(args):
            values.append(args[i + 1])
        elif arg.startswith(flag + "="):
            values.append(arg[len(flag) + 1:])
    return values


def import_path_kinds(args: Sequence[str]) -> list[str]:
    """The ``pkg.mod:NAME`` kinds of the ``--planner`` values in ``args`` (labels dropped)."""
    kinds = [value.partition("=")[2] or value for value in flag_values(args, PLANNER_FLAG)]
    return [kind.strip() for kind in kinds if ":" in kind]


def preload_planner_kinds(args: Sequence[str]) -> None:
    """Load the kinds ``args`` name by import path (after adding the ``--planner-path`` directories), so
    that the command's planner flags include their options; a kind that cannot be loaded ends the
    command here with its one-line error (exit 2)."""
    targets = import_path_kinds(args)
    paths = flag_values(args, PLANNER_PATH_FLAG)
    if not targets and not paths:
        return
    # only a command line that names a kind by import path pays for the planner table
    from letspi.assembly.planner_table import add_planner_paths, load_kind
    from letspi.cli.common import user_errors

    with user_errors():
        add_planner_paths(paths)
        for target in targets:
            load_kind(target)
