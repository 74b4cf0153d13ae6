"""``letspi fit``: offline fitting of baseline parameters."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.assembly.build import Builder
from letspi.assembly.resolve import goals_config
from letspi.cli.common import console, progress_bar, user_errors
from letspi.planners.frenet import FrenetSettings, save_frenet_weights
from letspi.planners.sf_params import save_sf_params
from letspi.scenario.provenance import refuse_suite_traffic
from letspi.scenario.store import load_scenarios, read_scenario_meta
from letspi.scenario.types import ScenarioBatch, concat_batches
from letspi_train.fitting.frenet import DEFAULT_GRID, fit_frenet_weights
from letspi_train.fitting.sf import fit_sf_params

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
    """Fit the `sf` baseline's social-force parameters. Objective: ADE plus weighted collisions."""
    with user_errors():
        meta = read_scenario_meta(scenarios)
        refuse_suite_traffic(scenarios, meta)
        batch = load_scenarios(scenarios)
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


def _load_unique(files: list[Path]) -> ScenarioBatch:
    """The scenarios of several files, each window once (files cut from one recording can share windows)."""
    batch = concat_batches([load_scenarios(f) for f in files])
    keys = np.array([f"{r}/{s}" for r, s in zip(batch.recording_key, batch.scenario_id, strict=True)])
    _, first = np.unique(keys, return_index=True)
    return batch.take(np.sort(first))


@app.command("frenet")
def fit_frenet(
    scenarios: Annotated[list[Path], typer.Option(help="Training scenario files (repeat; never evaluation seeds).")],
    out: Annotated[Path, typer.Option(help="Output JSON with the weights and their provenance.")],
    seed: Annotated[int, typer.Option(help="Seed of the by-vehicle split and subsampling.")] = 0,
    max_train: Annotated[int, typer.Option(help="At most this many training scenarios.")] = 4000,
    rounds: Annotated[int, typer.Option(help="Coordinate-descent sweeps over the weights.")] = 2,
    goals: Annotated[str, typer.Option(help="Goal source the planner will use (learned, kinematic).")] = "learned",
    collision_weight: Annotated[float, typer.Option(
        help="Objective weight of the at-fault collision rate [m].")] = 50.0,
) -> None:
    """Choose the `frenet` planner's cost weights. On training traffic split by vehicle; objective: ADE plus
    weighted at-fault collisions, low TTC and failures."""
    with user_errors():
        if goals == "oracle":
            raise ValueError("fit the weights with the goals the planner will use (learned or kinematic), "
                             "not the oracle")
        for f in scenarios:
            refuse_suite_traffic(f, read_scenario_meta(f))
        batch = _load_unique(scenarios)
        goals_used = goals_config(goals)
        goal_predictor = Builder(cache=None).goal_predictor(goals_used)
        settings = FrenetSettings()
        res = fit_frenet_weights(batch, goal_predictor, settings=settings, seed=seed, max_train=max_train,
                                 rounds=rounds, collision_weight=collision_weight, progress=console.print)
        provenance = {
            "scenarios_files": [str(f) for f in scenarios],
            "scenario_provenance": [read_scenario_meta(f).get("provenance") for f in scenarios],
            "n_scenarios": len(batch), "n_train": res.n_train, "n_validation": res.n_validation,
            "split": "by ego vehicle, 70 % train", "split_seed": seed, "max_train": max_train,
            "goals": goals_used.source, "neighbours": "idm",
            "lattice": settings.model_dump(exclude={"weights"}),
        }
        objective = {
            "definition": f"mean ADE [m] + {collision_weight} x at-fault collision rate + 5 x low-TTC rate "
                          "+ 5 x (1 - success rate), open loop against the recorded futures (train split); "
                          f"coordinate descent over {list(DEFAULT_GRID)} per weight, k_speed = 1",
            "start": res.start.as_dict(), "train": res.train.as_dict(),
            "validation_start": res.validation_start.as_dict(), "validation": res.validation.as_dict(),
            "evaluations": res.n_evaluations, "seconds": res.seconds,
        }
        save_frenet_weights(out, res.weights, provenance, objective)
    console.print(f"chosen {res.weights.model_dump()}")
    console.print(f"train J {res.start.objective:.3f} -> {res.train.objective:.3f}; validation: SR "
                  f"{res.validation_start.sr_pct:.2f} -> {res.validation.sr_pct:.2f} %, CR at fault "
                  f"{res.validation_start.cr_at_fault_pct:.2f} -> {res.validation.cr_at_fault_pct:.2f} % -> {out}")
