"""Planner flags from the planner table, in ``--help`` under their declared panel: ``@planner_options()`` is the
one place the CLI turns flags into ``PlannerOptions``; a command taking kinds from the whole table also takes
``--planner-path DIR`` (where kinds by import path are found). ``@setting_options`` does the same for other
declared settings (the closed loop's)."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from letspi.assembly.planner_table import add_planner_paths, planner_table
from letspi.planners.options import PLANNERS_PANEL, PlannerOption, PlannerOptions

F = TypeVar("F", bound=Callable[..., Any])
PLANNER_PATH = "planner_path"
PlannerPathOpt = Annotated[list[Path] | None, typer.Option(
    "--planner-path", metavar="DIR", rich_help_panel=PLANNERS_PANEL,
    help="Directory to import --planner package.module:NAME from (repeatable; the current directory is searched too).")]


def _flag_decls(option: PlannerOption[Any]) -> tuple[str, ...]:
    flag = option.cli_flag
    is_switch = option.type is bool or option.type == (bool | None)
    return (f"{flag}/--no-{flag.removeprefix('--')}",) if is_switch else (flag,)


def option_parameter(option: PlannerOption[Any]) -> inspect.Parameter:
    """The typer parameter of one planner option (keyword-only; its default is the declared one)."""
    info = typer.Option(*_flag_decls(option), help=option.describe(), rich_help_panel=option.panel, show_default=True)
    return inspect.Parameter(option.name, inspect.Parameter.KEYWORD_ONLY, default=option.default,
                             annotation=Annotated[option.type, info])


def planner_options(*, kinds: Sequence[str] | None = None, declared: Sequence[PlannerOption[Any]] | None = None,
                    exclude: Collection[str] = ()) -> Callable[[F], F]:
    """Decorate a command that has an ``options: PlannerOptions`` parameter (module docstring).

    kinds: the planner kinds whose options become flags (default: every kind of the table, as it is when
    the command is built: ``refresh_planner_flags``); declared: exactly these options instead; exclude:
    option names the command sets itself.
    """

    def flags_now() -> tuple[PlannerOption[Any], ...]:
        chosen = tuple(declared) if declared is not None else planner_table().options(kinds)
        unknown = set(exclude) - {o.name for o in chosen}
        if unknown:
            raise ValueError(f"exclude names no planner option: {', '.join(sorted(unknown))}")
        return tuple(o for o in chosen if o.name not in exclude)

    def decorate(command: F) -> F:
        signature = inspect.signature(command, eval_str=True)
        if "options" not in signature.parameters:
            raise TypeError(f"{command.__name__} needs an `options: PlannerOptions` parameter")
        own = [p for name, p in signature.parameters.items() if name != "options"]
        path_flag = [] if declared is not None or kinds is not None else [inspect.Parameter(
            PLANNER_PATH, inspect.Parameter.KEYWORD_ONLY, default=None, annotation=PlannerPathOpt)]

        @functools.wraps(command)
        def run(*args: Any, **kwargs: Any) -> Any:
            values = {o.name: kwargs.pop(o.name) for o in flags_now() if o.name in kwargs}
            add_planner_paths(kwargs.pop(PLANNER_PATH, None) or ())
            return command(*args, options=PlannerOptions(**values), **kwargs)

        def refresh() -> None:
            flags = flags_now()
            clash = {p.name for p in own} & {o.name for o in flags}
            if clash:
                raise ValueError(f"{command.__name__}: parameter(s) {', '.join(sorted(clash))} are planner options; "
                                 "exclude them or rename the parameter")
            run.__signature__ = signature.replace(  # type: ignore[attr-defined]
                parameters=[*own, *path_flag, *(option_parameter(o) for o in flags)])

        refresh()
        run.__annotations__ = {}  # the signature above is what typer reads
        run.refresh_planner_flags = refresh  # type: ignore[attr-defined]
        return run  # type: ignore[return-value]

    return decorate


def setting_options(declared: Sequence[PlannerOption[Any]], param: str) -> Callable[[F], F]:
    """Decorate a command that has a ``param: dict[str, Any]`` parameter: one flag per declared setting (name,
    type, default, unit, help and panel from the declaration, e.g. ``letspi.simulation.settings``); the command
    gets the values by setting name."""

    def decorate(command: F) -> F:
        signature = inspect.signature(command, eval_str=True)
        if param not in signature.parameters:
            raise TypeError(f"{command.__name__} needs a `{param}: dict[str, Any]` parameter")
        own = [p for name, p in signature.parameters.items() if name != param]
        clash = {p.name for p in own} & {o.name for o in declared}
        if clash:
            raise ValueError(f"{command.__name__}: parameter(s) {', '.join(sorted(clash))} are declared settings")

        @functools.wraps(command)
        def run(*args: Any, **kwargs: Any) -> Any:
            values = {o.name: kwargs.pop(o.name) for o in declared if o.name in kwargs}
            return command(*args, **{param: values}, **kwargs)

        run.__signature__ = signature.replace(  # type: ignore[attr-defined]
            parameters=[*own, *(option_parameter(o) for o in declared)])
        run.__annotations__ = {}
        return run  # type: ignore[return-value]

    return decorate
