"""``letspi fit``: offline fitting of baseline parameters."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from letspi.cli.common import console, progress_bar, user_errors
from letspi.planners.fit_sf import fit_sf_params
from letspi.planners.sf_params import save_sf_params
from letspi.scenario.store import load_scenarios, read_scenario_meta

app = typer.Typer(help="Fit baseline parameters offline.",
                  no_args_is_help=True, rich_markup_mode=None)


@app.command("sf")
def fit_sf(
    scenarios: Annotated[Path, typer.Option(help="Scenario file to fit on (a training split is taken).")],
    out: Annotated[Path, typer.Option(help="Output JSON with the parameters and their provenance.")],
    seed: Annotated[int, typer.Option(help="Seed of the by-vehicle split and subsampling.")] = 0,
    max_train: Annotated[int, typer.Option(help="At most this many training scenarios.")] = 2000,
    evaluations: Annotated[int, typer.Option(help="Objective evaluations (Nelder-Mead).")] = 200,
    collision_weight: Annotated[float, typer.Option(help="Objective weight of the collision rate [m].")] = 50.0,
) -> None:
    """Fit the fixed social-force parameters of the `sf` baseline (ADE + weighted collisions)."""
    with user_errors():
        batch = load_scenarios(scenarios)
        meta = read_scenario_meta(scenarios)
        with progress_bar() as bar:
            task = bar.add_task("fitting sf", total=evaluations + 1)
            res = fit_sf_params(batch, seed=seed, max_train=max_train, max_evaluations=evaluations,
                                collision_weight=collision_weight, progress=lambda k: bar.advance(task, k))
        provenance = {
            "scenarios_file": str(scenarios), "scenario_provenance": meta.get("provenance"),
            "n_scenarios": len(batch), "split": "by ego vehicle, 70 % train", "split_seed": seed,
            "max_train": max_train, "goals": "kinematic", "neighbours": "idm",
        }
        objective = {
            "definition": f"mean ADE [m] + {collision_weight} x collision rate + 5 x low-TTC rate (train split); "
                          "parameters bounded to TYPICAL_RANGES",
            "start_objective": res.start_objective, "train_objective": res.train_objective,
            "train_ade_m": res.train_ade_m, "train_collision_pct": res.train_collision_pct,
            "validation_ade_m": res.validation_ade_m, "validation_collision_pct": res.validation_collision_pct,
            "evaluations": res.n_evaluations, "seconds": res.seconds,
        }
        save_sf_params(out, res.params, provenance, objective)
    console.print(f"fitted {res.params.as_dict()}")
    console.print(f"objective {res.start_objective:.3f} -> {res.train_objective:.3f}; validation ADE "
                  f"{res.validation_ade_m:.2f} m, collisions {res.validation_collision_pct:.2f} % -> {out}")
