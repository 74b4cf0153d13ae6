"""Option help in panels: a command's options are listed under their ``rich_help_panel`` headings.

typer draws panels only with rich help; letspi prints plain help (``[train]`` stays text), so
``PanelledCommand`` groups the options itself, in ``PANEL_ORDER`` and then first-seen order, with
options of no panel (``--help``) last under "Options".
"""

from __future__ import annotations

from typing import Any

from typer.core import TyperCommand

#: the panels a command's options are shown in, in this order (others follow in first-seen order)
PANEL_ORDER = ("Data", "Planners", "Decision step", "LLM", "Closed loop", "Output")
#: the heading of options without a panel
OTHER = "Options"


class PanelledCommand(TyperCommand):
    """A typer command whose plain ``--help`` lists its options by panel (module docstring)."""

    def format_options(self, ctx: Any, formatter: Any) -> None:  # typer's own click types
        arguments: list[tuple[str, str]] = []
        panels: dict[str, list[tuple[str, str]]] = {}
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is None:
                continue
            if param.param_type_name == "argument":
                arguments.append(record)
            else:
                panels.setdefault(getattr(param, "rich_help_panel", None) or OTHER, []).append(record)
        if arguments:
            with formatter.section("Arguments"):
                formatter.write_dl(arguments)
        rank = {name: i for i, name in enumerate(PANEL_ORDER)}
        order = sorted(panels, key=lambda p: (p == OTHER, rank.get(p, len(rank))))  # stable: first-seen
        for panel in order:
            with formatter.section(panel):
                formatter.write_dl(panels[panel])


def with_panels(command: Any) -> Any:
    """``command`` and every sub-command of it with panelled help (typer builds plain ``TyperCommand``s)."""
    if type(command) is TyperCommand:
        command.__class__ = PanelledCommand  # adds one method, no state
    for sub in getattr(command, "commands", {}).values():
        with_panels(sub)
    return command
