"""The ``letspi`` command line. Sub-commands live in sibling modules."""

from __future__ import annotations

import os
from typing import Annotated

import typer

from letspi.cli import (
    analyze,
    bench,
    benchmark,
    data,
    demo,
    evaluate,
    export,
    fit,
    highway_env,
    llm,
    phases,
    planners,
    train,
    viz,
)
from letspi.cli.common import DEBUG_ENV
from letspi.evaluation.harness import letspi_version
from letspi.execution import interrupt


def _typer(help_text: str) -> typer.Typer:
    # plain help (no rich markup): "[train]" in "pip install 'letspi[train]'" stays text
    return typer.Typer(help=help_text, no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                       rich_markup_mode=None)


app = _typer("Safe highway trajectory planning with physics-informed LLMs (LetsPi).")


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


app.add_typer(data.app, name="data")
app.add_typer(analyze.app, name="analyze")
app.add_typer(bench.app, name="bench")
app.add_typer(benchmark.app, name="benchmark")
app.add_typer(fit.app, name="fit")
app.add_typer(export.app, name="export")
app.add_typer(highway_env.app, name="highway-env")
app.add_typer(train.app, name="train")
app.add_typer(llm.app, name="llm")
app.command("demo")(demo.demo)
app.command("evaluate")(evaluate.evaluate)
app.command("planners")(planners.planners)
app.command("collect")(phases.collect)
app.command("plan")(phases.plan)
app.command("ablate")(phases.ablate)
app.command("prompt")(phases.prompt)
app.command("plot")(viz.plot)
app.command("report")(viz.report)
app.command("compare")(viz.compare)


def main() -> None:
    with interrupt.handling():  # Ctrl-C: one line, exit 130, no orphaned processes (letspi.execution.interrupt)
        app()


if __name__ == "__main__":
    main()
