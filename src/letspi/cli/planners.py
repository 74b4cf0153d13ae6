"""``letspi planners``: every planner kind, what it is, whether it reads the recorded future, and its options."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer

from letspi.assembly.planner_table import ENTRY_POINT_GROUP, FutureUse, installed_kinds, kind_origin, planner_table
from letspi.planners.options import PlannerOption

FUTURE_HEADER = "reads future"


def _option_row(option: PlannerOption[Any]) -> dict[str, Any]:
    default = option.default if isinstance(option.default, str | int | float | bool | None) else str(option.default)
    return {"name": option.name, "flag": option.cli_flag, "default": default, "unit": option.unit,
            "help": option.describe()}


def planners(
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON list instead of a table.")] = False,
) -> None:
    """List the planner kinds that --planner accepts. Each with what it is, whether it reads the recorded
    future, and the flags of its settings."""
    table = planner_table()
    rows: list[dict[str, Any]] = [{"kind": k.name, "description": k.description, "reads_future": k.future.value,
             "config": k.config_class.__name__, "dual_rate": k.dual_rate, "source": kind_origin(k.name),
             "options": [_option_row(o) for o in k.options]} for k in table.kinds]
    problems = installed_kinds().problems
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    kind_w = max(len(row["kind"]) for row in rows)
    future_w = max(len(row["reads_future"]) for row in [*rows, {"reads_future": FUTURE_HEADER}])
    typer.echo(f"{'kind':<{kind_w}}  {FUTURE_HEADER:<{future_w}}  description")
    for row in rows:
        source = "" if row["source"] == "built in" else f" [{row['source']}]"
        typer.echo(f"{row['kind']:<{kind_w}}  {row['reads_future']:<{future_w}}  {row['description']}{source}")
        flags = " ".join(o["flag"] for o in row["options"])
        if flags:
            typer.echo(f"{'':<{kind_w}}  {'':<{future_w}}  settings: {flags}")
    typer.echo(f"\n{FUTURE_HEADER}: {FutureUse.ALWAYS.value} = replays the recorded future (a reference, not a "
               f"planner); {FutureUse.ORACLE_INPUTS.value} = with --goals oracle or --neighbours "
               "ground_truth_oracle. `letspi evaluate --help` describes every setting. Installed packages add kinds "
               f"through the entry-point group {ENTRY_POINT_GROUP!r}; --planner package.module:NAME loads one by its "
               "import path.")
    for problem in problems:
        typer.echo(f"left out: {problem}", err=True)
