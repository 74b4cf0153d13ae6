"""The ``letspi`` command line. Sub-commands live in sibling modules, imported when a command is run.

``COMMANDS`` names every command, the module and attribute that define it and its one-line summary:
``letspi --help`` prints the summaries without importing a command module, and ``letspi CMD ...`` imports
only CMD's module. Other distributions add commands through the ``letspi.commands`` entry-point group
(``letspi-train`` adds ``train`` and ``fit``, ``letspi-interop`` ``highway-env`` and ``export``). Planner kinds
named by import path are loaded before a command's options are parsed (``letspi.cli.startup``).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterator, Mapping, MutableMapping
from importlib.metadata import PackageNotFoundError, entry_points, version
from typing import Annotated, Any

import typer
from typer._click.exceptions import UsageError
from typer.core import TyperGroup

from letspi.cli.entry import CommandEntry
from letspi.cli.help import PanelledCommand, with_panels
from letspi.cli.startup import DEBUG_ENV, preload_planner_kinds
from letspi.execution import interrupt

#: every command of ``letspi``, in the order of ``letspi --help``
COMMANDS: dict[str, CommandEntry] = {
    "demo": CommandEntry("letspi.cli.demo", "demo", "The main job on generated traffic and the embedded model"),
    "evaluate": CommandEntry("letspi.cli.evaluate", "evaluate", "Evaluate planners on scenarios (open or closed loop)"),
    "planners": CommandEntry("letspi.cli.planners", "planners",
                             "List the planner kinds --planner accepts, with their flags"),
    "collect": CommandEntry("letspi.cli.phases", "collect",
                            "LetsPi's memory collection: prompt, reflection, stored experiences"),
    "plan": CommandEntry("letspi.cli.phases", "plan",
                         "Plan one scenario and show parameters, goal, trajectory and metrics"),
    "ablate": CommandEntry("letspi.cli.phases", "ablate", "Run one of the paper's ablations and print its table"),
    "prompt": CommandEntry("letspi.cli.phases", "prompt",
                           "Print the rendered prompt for one scenario (calls no model)"),
    "plot": CommandEntry("letspi.cli.viz", "plot", "Draw one scenario: trajectories, time-space diagram, reflections"),
    "report": CommandEntry("letspi.cli.viz", "report", "Write a self-contained HTML report of a results directory"),
    "compare": CommandEntry("letspi.cli.viz", "compare", "Compare two results directories on the windows both hold"),
    "data": CommandEntry("letspi.cli.data", "app", "HighD data: generate with SUMO, extract scenarios, inspect"),
    "analyze": CommandEntry("letspi.cli.analyze", "app", "Analyse what the data allows a planner to gain"),
    "benchmark": CommandEntry("letspi.cli.benchmark", "app",
                              "Versioned benchmark suites: list, show, run, summary, power"),
    "llm": CommandEntry("letspi.cli.llm", "app", "LLM backends: check a spec, list embedded models, benchmark"),
}
#: the entry-point group through which other distributions add commands: each entry point names a
#: ``dict[str, CommandEntry]`` (e.g. ``letspi_train.commands:COMMANDS``)
COMMANDS_GROUP = "letspi.commands"
#: commands of letspi's companion distributions (packages/ in the repository), named when they are missing
COMPANIONS = {"train": "letspi-train", "fit": "letspi-train", "highway-env": "letspi-interop",
              "export": "letspi-interop"}


def _add_plugin_commands() -> None:
    for ep in sorted(entry_points(group=COMMANDS_GROUP), key=lambda e: e.name):
        for name, entry in ep.load().items():
            if name in COMMANDS:
                raise RuntimeError(f"entry point {ep.value} ({COMMANDS_GROUP}) redefines the command {name!r}")
            COMMANDS[name] = entry


_add_plugin_commands()


# click objects are typed Any here: typer builds them from its own copy of click (typer._click)
def load_command(name: str) -> Any:
    """The click command ``name`` of ``COMMANDS`` (its module is imported here), with grouped option help."""
    entry = COMMANDS[name]
    target: Any = getattr(importlib.import_module(entry.module), entry.attribute)
    callbacks = [info.callback for info in target.registered_commands] if isinstance(target, typer.Typer) else [target]
    for callback in callbacks:  # planner flags from the table as it is now (kinds loaded by import path join it)
        refresh = getattr(callback, "refresh_planner_flags", None)
        if refresh is not None:
            refresh()
    command: Any
    if isinstance(target, typer.Typer):
        command = typer.main.get_group(target)  # a group even with one sub-command (letspi export commonroad)
    else:  # one command: a Typer holding only it is that command
        holder = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)
        holder.command(name, cls=PanelledCommand)(target)
        command = typer.main.get_command(holder)
    command.name = name
    return with_panels(command)


class LazyCommands(MutableMapping[str, Any]):
    """The top-level commands by name: all of ``COMMANDS`` are listed, each is imported when looked up."""

    def __init__(self, loaded: Mapping[str, Any]) -> None:
        self._loaded = dict(loaded)

    def __getitem__(self, name: str) -> Any:
        if name not in self._loaded:
            if name not in COMMANDS:
                raise KeyError(name)
            self._loaded[name] = load_command(name)
        return self._loaded[name]

    def __setitem__(self, name: str, command: Any) -> None:
        self._loaded[name] = command

    def __delitem__(self, name: str) -> None:
        del self._loaded[name]

    def __iter__(self) -> Iterator[str]:
        yield from self._loaded
        yield from (name for name in COMMANDS if name not in self._loaded)

    def __len__(self) -> int:
        return len(self._loaded.keys() | COMMANDS.keys())


class LazyGroup(TyperGroup):
    """The top-level group: a command's module is imported when it runs (or its help is asked), never for
    ``letspi --help``; kinds named by import path are loaded before the command's options are parsed."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        self.commands = LazyCommands(self.commands)

    def list_commands(self, ctx: Any) -> list[str]:
        return list(self.commands)

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        with formatter.section("Commands"):
            formatter.write_dl([(name, entry.summary) for name, entry in COMMANDS.items()])

    def resolve_command(self, ctx: Any, args: list[str]) -> tuple[str | None, Any, list[str]]:
        if args and args[0] in COMMANDS:
            preload_planner_kinds(args[1:])
        elif args and args[0] in COMPANIONS:
            package = COMPANIONS[args[0]]
            raise UsageError(f"letspi {args[0]} comes with the companion distribution {package}: "
                         f"pip install -e packages/{package} (from the repository root)", ctx)
        return super().resolve_command(ctx, args)


app = typer.Typer(cls=LazyGroup, help="Safe highway trajectory planning with physics-informed LLMs (LetsPi).",
                  no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)


def letspi_version() -> str:
    """The installed distribution's version ("unknown" in a source tree that is not installed)."""
    try:
        return version("letspi")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def _version(value: bool) -> None:
    if value:
        typer.echo(f"letspi {letspi_version()}")
        raise typer.Exit()


@app.callback()
def main_options(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Print the version and exit.")] = False,
    debug: Annotated[bool, typer.Option("--debug", help=f"Show tracebacks instead of one-line errors "
                                                        f"(also {DEBUG_ENV}=1).")] = False,
) -> None:
    """Safe highway trajectory planning with physics-informed LLMs (LetsPi)."""
    if debug:
        os.environ[DEBUG_ENV] = "1"


def main() -> None:
    with interrupt.handling():  # Ctrl-C: one line, exit 130, no orphaned processes (letspi.execution.interrupt)
        app()


if __name__ == "__main__":
    main()
