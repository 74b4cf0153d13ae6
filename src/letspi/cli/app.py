"""The ``letspi`` command line. Sub-commands live in sibling modules; imports of heavy modules
happen inside the commands so ``letspi --help`` stays fast."""

from __future__ import annotations

import typer

from letspi.cli import bench, data, demo, evaluate, fit, llm, phases, train, viz

app = typer.Typer(
    name="letspi",
    help="Safe highway trajectory planning with physics-informed LLMs (LetsPi).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(data.app, name="data")
app.add_typer(bench.app, name="bench")
app.add_typer(fit.app, name="fit")
app.add_typer(train.app, name="train")
app.add_typer(llm.app, name="llm")
app.command("demo")(demo.demo)
app.command("evaluate")(evaluate.evaluate)
app.command("collect")(phases.collect)
app.command("plan")(phases.plan)
app.command("ablate")(phases.ablate)
app.command("prompt")(phases.prompt)
app.command("plot")(viz.plot)
app.command("report")(viz.report)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
