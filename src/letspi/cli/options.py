"""Planner flags from the planner table (under "Planner options" in ``--help``): ``@planner_options()`` is the one
place the CLI turns flags into ``PlannerOptions``."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Collection, Sequence
from typing import Annotated, Any, TypeVar

import typer

from letspi.assembly.planner_table import planner_table
from letspi.planners.options import PlannerOption, PlannerOptions

F = TypeVar("F", bound=Callable[..., Any])
PANEL = "Planner options"


def _flag_decls(option: PlannerOption[Any]) -> tuple[str, ...]:
    flag = option.cli_flag
    is_switch = option.type is bool or option.type == (bool | None)
    return (f"{flag}/--no-{flag.removeprefix('--')}",) if is_switch else (flag,)


def option_parameter(option: PlannerOption[Any]) -> inspect.Parameter:
    """The typer parameter of one planner option (keyword-only; its default is the declared one)."""
    info = typer.Option(*_flag_decls(option), help=option.describe(), rich_help_panel=PANEL, show_default=True)
    return inspect.Parameter(option.name, inspect.Parameter.KEYWORD_ONLY, default=option.default,
                             annotation=Annotated[option.type, info])


def planner_options(*, kinds: Sequence[str] | None = None, declared: Sequence[PlannerOption[Any]] | None = None,
                    exclude: Collection[str] = ()) -> Callable[[F], F]:
    """Decorate a command that has an ``options: PlannerOptions`` parameter: one flag per option of ``kinds``
    (default: every kind), or exactly ``declared``; ``exclude``: option names the command sets itself."""
    chosen = tuple(declared) if declared is not None else planner_table().options(kinds)
    unknown = set(exclude) - {o.name for o in chosen}
    if unknown:
        raise ValueError(f"exclude names no planner option: {', '.join(sorted(unknown))}")
    flags = tuple(o for o in chosen if o.name not in exclude)

    def decorate(command: F) -> F:
        signature = inspect.signature(command, eval_str=True)
        if "options" not in signature.parameters:
            raise TypeError(f"{command.__name__} needs an `options: PlannerOptions` parameter")
        own = [p for name, p in signature.parameters.items() if name != "options"]
        clash = {p.name for p in own} & {o.name for o in flags}
        if clash:
            raise ValueError(f"{command.__name__}: parameter(s) {', '.join(sorted(clash))} are planner options; "
                             "exclude them or rename the parameter")

        @functools.wraps(command)
        def run(*args: Any, **kwargs: Any) -> Any:
            values = {o.name: kwargs.pop(o.name) for o in flags if o.name in kwargs}
            return command(*args, options=PlannerOptions(**values), **kwargs)

        run.__signature__ = signature.replace(  # type: ignore[attr-defined]
            parameters=[*own, *(option_parameter(o) for o in flags)])
        run.__annotations__ = {}  # the signature above is what typer reads
        return run  # type: ignore[return-value]

    return decorate
