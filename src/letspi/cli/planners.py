"""``letspi planners``: every planner kind, what it is and whether it reads the recorded future."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from letspi.assembly.planner_table import PLANNER_TABLE, FutureUse

FUTURE_HEADER = "reads future"


def planners(
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON list instead of a table.")] = False,
) -> None:
    """List the planner kinds that --planner accepts (from the one table in letspi.assembly.planner_table)."""
    rows = [{"kind": k.name, "description": k.description, "reads_future": k.future.value,
             "config": k.config_class.__name__} for k in PLANNER_TABLE]
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    kind_w = max(len(row["kind"]) for row in rows)
    future_w = max(len(row["reads_future"]) for row in [*rows, {"reads_future": FUTURE_HEADER}])
    typer.echo(f"{'kind':<{kind_w}}  {FUTURE_HEADER:<{future_w}}  description")
    for row in rows:
        typer.echo(f"{row['kind']:<{kind_w}}  {row['reads_future']:<{future_w}}  {row['description']}")
    typer.echo(f"\n{FUTURE_HEADER}: {FutureUse.ALWAYS.value} = replays the recorded future (a reference, not a "
               f"planner); {FutureUse.ORACLE_INPUTS.value} = with --goals oracle or --neighbour-mode "
               "ground_truth_oracle.")
