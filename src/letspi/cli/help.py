"""Plain help, readable: options in panels, sub-commands with whole first sentences.

typer draws panels only with rich help; letspi prints plain help (``[train]`` stays text), so
``PanelledCommand`` groups the options itself, in ``PANEL_ORDER`` and then first-seen order, with
options of no panel (``--help``) last under "Options". click cuts a sub-command's summary at the first
period ("(e.g." included) and then at the terminal's width; ``SummaryGroup`` lists each sub-command
with the whole first sentence of its help, wrapped.
"""

from __future__ import annotations

import re
from typing import Any

from typer.core import TyperCommand, TyperGroup

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


def first_sentence(text: str) -> str:
    """The first sentence of a help text's first paragraph, without its period ("e.g." and "i.e." do not
    end it)."""
    paragraph = " ".join(text.strip().split("\n\n")[0].split())
    for end in re.finditer(r"\.(?=\s|$)", paragraph):
        head = paragraph[: end.start()]
        if not re.search(r"\b(e\.g|i\.e|cf|vs)$", head):
            return head
    return paragraph


class SummaryGroup(TyperGroup):
    """A typer group whose help lists each sub-command with the whole first sentence of its help, wrapped."""

    def format_commands(self, ctx: Any, formatter: Any) -> None:  # typer's own click types
        rows = [(name, command.short_help or first_sentence(command.help or ""))
                for name in self.list_commands(ctx) if (command := self.get_command(ctx, name)) is not None
                and not command.hidden]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def with_panels(command: Any) -> Any:
    """``command`` and every sub-command of it with panelled help and whole summaries (typer builds plain
    ``TyperCommand``s and ``TyperGroup``s; these subclasses add methods only)."""
    if type(command) is TyperCommand:
        command.__class__ = PanelledCommand
    elif type(command) is TyperGroup:
        command.__class__ = SummaryGroup
    for sub in getattr(command, "commands", {}).values():
        with_panels(sub)
    return command
