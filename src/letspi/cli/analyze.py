"""``letspi analyze``: what the data says a planner could gain."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from letspi.analysis.decisions import decisions_markdown, paired_rows, planner_report
from letspi.analysis.headroom import headroom
from letspi.analysis.options import OptionOutcomes, OptionRun, random_option_table
from letspi.assembly.build import Builder
from letspi.assembly.resolve import goals_config
from letspi.cli.common import console, progress_bar, user_errors
from letspi.fsutil import atomic_write_text
from letspi.method.decide import OptionTable, gate_features, load_presets, load_risk_model, with_defaults
from letspi.planners.sf_params import load_sf_params
from letspi.safety.adverse import AdverseSettings
from letspi.scenario.risk_features import risk_features
from letspi.scenario.split import vehicle_keys
from letspi.scenario.store import load_scenarios

app = typer.Typer(help="Analyse what the data allows a planner to gain.", no_args_is_help=True, rich_markup_mode=None)


def _scored(run: OptionRun, label: str) -> OptionOutcomes:
    with progress_bar() as bar:
        task = bar.add_task(label, total=len(run.batch))
        return run.run(progress=lambda k: bar.advance(task, k))


@app.command("headroom")
def headroom_cmd(
    scenarios: Annotated[Path, typer.Option(help="Scenario file (with the recorded future: hindsight).")],
    out: Annotated[Path, typer.Option(help="Output directory (cached option outcomes, headroom.md/json); "
                                           "rerun to resume.")],
    n_options: Annotated[int, typer.Option("--options", help="Random answers besides the presets (shared by all "
                                                             "windows; the first is the defaults).")] = 96,
    presets: Annotated[Path | None, typer.Option(help="Preset file (default: the shipped presets).")] = None,
    sf_params: Annotated[Path | None, typer.Option(help="Fitted sf parameters (default: the shipped fit).")] = None,
    goals: Annotated[str, typer.Option(help="Goal source of the plans: learned or kinematic.")] = "learned",
    folds: Annotated[int, typer.Option(help="Folds of the grouped (by vehicle) cross-validation.")] = 5,
    seed: Annotated[int, typer.Option(help="Seed of the random answers and of the folds.")] = 0,
    max_windows: Annotated[int | None, typer.Option("--max", help="Only the first N windows.")] = None,
) -> None:
    """What any choice of the LLM's eight numbers could gain. Paired on one scenario file: the defaults,
    the best constant, hindsight oracles, the no-model rule, a history-only chooser (grouped CV) and the
    risk AUCs."""
    with user_errors():
        if goals not in ("learned", "kinematic"):
            raise ValueError("--goals must be learned or kinematic")
        batch = load_scenarios(scenarios, None if max_windows is None else np.arange(max_windows))
        params, _ = load_sf_params(sf_params)
        goal_predictor = Builder(cache=None).goal_predictor(goals_config(goals))
        preset_table = with_defaults(load_presets(presets)[0], params)
        random = random_option_table(params, n_options, seed)
        checked = _scored(OptionRun.create(batch, preset_table, out / "presets", goal_predictor, params, goals=goals,
                                           checks=True, adverse=AdverseSettings()), "presets (checked)")
        free = _scored(OptionRun.create(batch, random, out / "random", goal_predictor, params, goals=goals),
                       "random answers")
        table = OptionTable((*preset_table.names, *(f"random:{n}" for n in random.names[1:])),
                            np.concatenate([preset_table.values, random.values[1:]]))
        outcomes = checked.with_options(free.take_options(np.arange(1, len(random))))
        hist = batch.history()
        model, _ = load_risk_model()
        gate = model.score(gate_features(hist, checked.predicted_safe[:, 0], checked.adverse_failed[:, 0],
                                         [str(a) for a in AdverseSettings().futures]))
        result = headroom(outcomes, table, list(range(len(preset_table))), risk_features(hist), vehicle_keys(hist),
                          folds=folds, seed=seed, gate_scores=gate)
        atomic_write_text(out / "headroom.json", json.dumps({**result.to_json(), "scenarios": str(scenarios),
                                                             "presets": list(preset_table.names)}, indent=2) + "\n")
        atomic_write_text(out / "headroom.md", result.to_markdown() + "\n")
    console.print(result.to_markdown())
    console.print(f"-> {out / 'headroom.md'}")


@app.command("decisions")
def decisions_cmd(
    results: Annotated[list[Path], typer.Option("--results", help="Results directory of `letspi evaluate` "
                                                "(repeat: pooled, e.g. one per layout).")],
    planner: Annotated[list[str], typer.Option(help="Planner label to report (repeat).")],
    reference: Annotated[str, typer.Option(help="The planner every other one is paired with.")] = "sf",
    out: Annotated[Path | None, typer.Option(help="Write decisions.json and decisions.md here.")] = None,
) -> None:
    """What deciding planners decided and what it bought. Pooled over results directories and paired with
    the reference: rates with McNemar counts, progress, decision shares, defaults kept or changed where
    the reference was safe or collided, the share consulted and the median live planning time."""
    with user_errors():
        reports = [planner_report(paired_rows(results, name, reference), name, reference) for name in planner]
        text = decisions_markdown(reports)
        if out is not None:
            atomic_write_text(out / "decisions.json", json.dumps({"results": [str(r) for r in results],
                                                                  "reports": reports}, indent=2) + "\n")
            atomic_write_text(out / "decisions.md", text + "\n")
    console.print(text)
