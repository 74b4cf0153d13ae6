"""``letspi train``: train the learned goal predictor and the GNP baseline (needs torch==2.13.0)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from letspi.assembly.build import Builder
from letspi.assembly.resolve import goals_config
from letspi.cli.common import command_line, console, progress_bar, user_errors
from letspi.fsutil import provenance_record, writer_lock
from letspi.learned.goal_model import LearnedGoalPredictor
from letspi.learned.hyperparams import GnpTrainConfig, GoalTrainConfig
from letspi.learned.weights import save_weights
from letspi.llm.models import packaged_smollm2_path
from letspi.llm.schema import NUMERIC_FIELDS
from letspi.planners.sf_params import load_sf_params
from letspi.scenario.provenance import refuse_suite_traffic
from letspi.scenario.store import load_scenarios, read_scenario_meta

app = typer.Typer(help="Train the learned models and the LLM's adapter (letspi-train; needs torch==2.13.0).",
                  no_args_is_help=True, rich_markup_mode=None)

ScenariosOpt = Annotated[list[Path], typer.Option("--scenarios", help="Scenario file(s) to train on "
                                                  "(repeat the option for several; split by ego vehicle).")]
OutOpt = Annotated[Path, typer.Option(help="Output model directory (weights.npz + manifest.json).")]
SeedOpt = Annotated[int, typer.Option(help="Seed of the split, initialisation and batch order.")]
ThreadsOpt = Annotated[int, typer.Option(help="torch CPU threads (1 keeps runs reproducible and polite).")]
EpochsOpt = Annotated[int, typer.Option(help="Training epochs.")]
MaxTrainOpt = Annotated[int | None, typer.Option(help="At most this many training scenarios.")]
DataNoteOpt = Annotated[str | None, typer.Option(
    help="Where the data came from, stored in the manifest (e.g. the `letspi data generate` seeds).")]


def _require_torch() -> None:
    try:
        import torch  # noqa: F401
    except ImportError as exc:
        console.print("[red]error:[/red] training needs torch: pip install 'letspi\\[train]' (torch==2.13.0)")
        raise typer.Exit(code=2) from exc


def _print_validation(validation: dict[str, Any]) -> None:
    for name, values in validation.items():
        if isinstance(values, dict):
            shown = ", ".join(f"{k} {v:.3f}" for k, v in values.items() if isinstance(v, float) and k != "n")
            console.print(f"  {name}: {shown}")


@app.command("goals")
def train_goals(
    scenarios: ScenariosOpt,
    out: OutOpt,
    epochs: EpochsOpt = GoalTrainConfig.epochs,
    seed: SeedOpt = GoalTrainConfig.seed,
    n_goals: Annotated[int, typer.Option(help="Number of candidate goals K.")] = GoalTrainConfig.n_goals,
    max_train: MaxTrainOpt = GoalTrainConfig.max_train,
    threads: ThreadsOpt = GoalTrainConfig.threads,
    data_note: DataNoteOpt = None,
) -> None:
    """Train the transformer multi-goal predictor. Winner-takes-all over K goals at the 5 s horizon."""
    _require_torch()
    from letspi_train.learned.data import load_training_scenarios
    from letspi_train.learned.goal_train import train_goal_model

    with user_errors(), writer_lock(out, command_line()):
        if epochs < 1:
            raise ValueError("--epochs must be >= 1")
        batch, infos = load_training_scenarios(scenarios)
        cfg = GoalTrainConfig(epochs=epochs, seed=seed, n_goals=n_goals, max_train=max_train, threads=threads)
        with progress_bar() as bar:
            task = bar.add_task("training goals", total=epochs)
            res = train_goal_model(batch, cfg, progress=lambda k: bar.advance(task, k),
                                   manifest_extra={"data": {"scenario_files": infos, "note": data_note},
                                                   "training": {"command": command_line()}})
        save_weights(out, res.arrays, res.manifest)
    console.print(f"goal model -> {out} ({res.manifest['training']['seconds']:.0f} s); validation:")
    _print_validation(res.manifest["validation"])


@app.command("gnp")
def train_gnp(
    scenarios: ScenariosOpt,
    out: OutOpt,
    epochs: EpochsOpt = GnpTrainConfig.epochs,
    seed: SeedOpt = GnpTrainConfig.seed,
    goal_weights: Annotated[Path | None, typer.Option(
        help="Goal model directory for the rollout goals (default: $LETSPI_GOAL_WEIGHTS or the shipped one).")] = None,
    sf_params: Annotated[Path | None, typer.Option(
        help="Fixed SF parameters the weights scale (default: the shipped `sf` fit).")] = None,
    max_train: MaxTrainOpt = GnpTrainConfig.max_train,
    neighbours: Annotated[str, typer.Option(
        help="Neighbour prediction: idm or constant_velocity.")] = GnpTrainConfig.neighbour_mode,
    threads: ThreadsOpt = GnpTrainConfig.threads,
    data_note: DataNoteOpt = None,
) -> None:
    """Train the GNP baseline end to end. Tau per scene and a repulsion weight per neighbour, through the
    differentiable social force rollout (predicted goals and predicted neighbours)."""
    _require_torch()
    from letspi_train.learned.data import load_training_scenarios
    from letspi_train.learned.gnp_train import train_gnp_model

    with user_errors(), writer_lock(out, command_line()):
        if epochs < 1:
            raise ValueError("--epochs must be >= 1")
        if neighbours not in ("idm", "constant_velocity"):
            raise ValueError("--neighbours must be idm or constant_velocity (never the recorded future)")
        batch, infos = load_training_scenarios(scenarios)
        base, _ = load_sf_params(sf_params)
        goals = (LearnedGoalPredictor.from_dir(goal_weights) if goal_weights is not None
                 else Builder(cache=None).goal_predictor(goals_config("learned")))
        cfg = GnpTrainConfig(epochs=epochs, seed=seed, max_train=max_train, neighbour_mode=neighbours,
                             threads=threads)
        with progress_bar() as bar:
            task = bar.add_task("training gnp", total=epochs + 1)
            res = train_gnp_model(batch, cfg, base, goals, progress=lambda k: bar.advance(task, k),
                                  manifest_extra={"data": {"scenario_files": infos, "note": data_note},
                                                  "training": {"command": command_line(),
                                                               "goal_weights": str(goal_weights or "default"),
                                                               "sf_params": str(sf_params or "shipped")}})
        save_weights(out, res.arrays, res.manifest)
    console.print(f"gnp model -> {out} ({res.manifest['training']['seconds']:.0f} s); validation:")
    _print_validation(res.manifest["validation"])


@app.command("llm-data")
def train_llm_data(
    scenarios: Annotated[Path, typer.Option("--scenarios", help="Training scenario file (never an evaluation set).")],
    out: Annotated[Path, typer.Option(help="Output labels directory (labels.parquet + manifest.json); "
                                      "an interrupted run resumes.")],
    seed: SeedOpt = 0,
    max_scenarios: Annotated[int | None, typer.Option("--max", help="Label only the first N scenarios.")] = None,
    n_random: Annotated[int, typer.Option(help="Random candidates per scenario.")] = 48,
    n_rounds: Annotated[int, typer.Option(help="Local refinement rounds.")] = 2,
    n_local: Annotated[int, typer.Option(help="Candidates per refinement round.")] = 24,
    sf_params: Annotated[Path | None, typer.Option(
        help="Fitted SF parameters (defaults, r_col_m; default: the shipped `sf` fit).")] = None,
    goals: Annotated[str, typer.Option(help="Goal source of the plans: learned or kinematic.")] = "learned",
) -> None:
    """Make physics-verified labels for the LLM. Per scenario, search the six social-force parameters and
    the two goal factors, scored against the RECORDED future (hindsight; training only)."""
    from letspi_train.finetune.labels import PARTS_DIR, LabelRun, LabelSearch

    with user_errors(resumes=True) as tally, writer_lock(out, command_line()):
        if goals not in ("learned", "kinematic"):
            raise ValueError("--goals must be learned or kinematic (labels never use oracle goals)")
        search = LabelSearch(n_random=n_random, n_rounds=n_rounds, n_local=n_local)
        refuse_suite_traffic(scenarios, read_scenario_meta(scenarios))
        batch = load_scenarios(scenarios)
        if max_scenarios is not None:
            batch = batch.take(slice(0, max_scenarios))
        n = len(batch)
        # part-<start>.parquet holds scenarios start .. start + chunk - 1 (letspi_train.finetune.labels)
        tally.track(n, lambda: sum(min(search.chunk, n - int(p.stem.split("-")[1]))
                                   for p in (out / PARTS_DIR).glob("part-*.parquet")))
        params, _ = load_sf_params(sf_params)
        goal_predictor = Builder(cache=None).goal_predictor(goals_config(goals))
        labeller = LabelRun(scenarios_path=scenarios, batch=batch, out=out, goal_predictor=goal_predictor,
                            params=params, search=search, seed=seed, command=command_line())
        with progress_bar() as bar:
            task = bar.add_task("labelling", total=len(batch))
            manifest = labeller.run(progress=lambda k: bar.advance(task, k))
    console.print(f"labels -> {out}: {manifest['n_propose']} propose + {manifest['n_refine']} refine rows from "
                  f"{manifest['n_scenarios']} scenarios in {manifest['elapsed_s']:.0f} s "
                  f"({manifest['scenarios_per_s']:.2f} scenarios/s); safe labels "
                  f"{100 * (manifest['label_safe_share'] or 0):.1f} %")


@app.command("mlp")
def train_mlp_cmd(
    data: Annotated[list[Path], typer.Option("--data", help="Labels directory from `letspi train llm-data` "
                                             "(repeat for several).")],
    out: OutOpt,
    epochs: EpochsOpt = 300,
    hidden: Annotated[int, typer.Option(help="Hidden units per layer.")] = 64,
    seed: SeedOpt = 0,
    threads: ThreadsOpt = 1,
) -> None:
    """Train the `mlp` regressor ablation. It predicts the eight LLM answers from the matching features, on
    the physics-verified labels the LLM is fine-tuned on (weights.npz + manifest.json; NumPy inference)."""
    _require_torch()
    from letspi_train.finetune.mlp_train import MlpTrainConfig, load_training_rows, train_mlp

    with user_errors(), writer_lock(out, command_line()):
        if epochs < 1:
            raise ValueError("--epochs must be >= 1")
        feats, targets, vehicles, infos = load_training_rows(data)
        if len(feats) < 10:
            raise ValueError(f"{', '.join(map(str, data))}: only {len(feats)} safe propose labels; need >= 10")
        sf = infos[0].get("sf_params") or {}
        defaults = np.array([float(sf.get(f, np.nan)) if f in sf else (0.4 if f == "lon_factor" else 0.0)
                             for f in NUMERIC_FIELDS])
        cfg = MlpTrainConfig(hidden=hidden, epochs=epochs, seed=seed, threads=threads)
        res = train_mlp(feats, targets, vehicles, cfg, defaults=defaults if np.isfinite(defaults).all() else None)
        res.manifest["data"]["labels"] = infos
        res.manifest["training"]["command"] = command_line()
        save_weights(out, res.arrays, res.manifest)
    val = res.manifest["validation"]
    console.print(f"mlp -> {out} ({res.manifest['training']['seconds']:.0f} s, {len(feats)} labels); "
                  f"validation RMSE (n={val['n']}):")
    for f, v in val["rmse"].items():
        base = val.get("rmse_sf_defaults", {}).get(f)
        console.print(f"  {f}: {v:.3f}" + (f" (sf defaults {base:.3f})" if base is not None else ""))


def _llm_examples(data: list[Path], scenarios: Path | None,
                  max_scenarios: int | None) -> tuple[list[Any], dict[str, Any]]:
    """The chat examples of one or several label directories (``letspi_train.finetune.data``)."""
    from letspi_train.finetune.data import build_examples, build_examples_many

    goal_predictor = Builder(cache=None).goal_predictor(goals_config("learned"))
    if scenarios is not None and len(data) > 1:
        raise ValueError("--scenarios names the scenario file of one labels directory; with several --data "
                         "each directory's manifest names its own")
    if len(data) == 1:
        examples, info = build_examples(data[0], goal_predictor, scenarios=scenarios, max_scenarios=max_scenarios)
    else:
        examples, info = build_examples_many(data, goal_predictor, max_scenarios=max_scenarios)
    if not examples:
        raise ValueError(f"{', '.join(map(str, data))}: no safe labels to train on")
    return list(examples), provenance_record(info)  # the manifest names no directory of this machine


#: the output of `train llm` and `train dpo`
AdapterOutOpt = Annotated[Path, typer.Option(help="Output directory (adapter.gguf, manifest.json, peft/); a killed run "
                                             "resumes from its checkpoint when the same command is run again.")]


@app.command("llm")
def train_llm(
    data: Annotated[list[Path], typer.Option("--data", help="Labels directory from `letspi train llm-data` "
                                             "(repeat for several; split by ego vehicle).")],
    out: AdapterOutOpt,
    epochs: Annotated[float, typer.Option(help="Passes over the training examples (fractions allowed).")] = 1.0,
    lr: Annotated[float, typer.Option(help="Peak learning rate (AdamW, warm-up then linear decay).")] = 3e-4,
    rank: Annotated[int, typer.Option(help="LoRA rank.")] = 8,
    alpha: Annotated[int, typer.Option(help="LoRA alpha (scale alpha / rank).")] = 16,
    batch_size: Annotated[int, typer.Option(help="Examples per optimiser step.")] = 8,
    seed: SeedOpt = 0,
    max_steps: Annotated[int | None, typer.Option(help="Stop after this many optimiser steps.")] = None,
    max_scenarios: Annotated[int | None, typer.Option(
        "--max-scenarios", help="Use only the first N labelled scenarios.")] = None,
    scenarios: Annotated[Path | None, typer.Option(
        help="The scenario file the labels index (default: the labels manifest's scenarios_path).")] = None,
    val_fraction: Annotated[float, typer.Option(help="Share of scenarios held out for the validation loss.")] = 0.1,
    verify: Annotated[int, typer.Option(help="Prompts on which torch and llama.cpp outputs are compared.")] = 3,
    threads: Annotated[int, typer.Option(help="torch CPU threads.")] = 2,
    layers: Annotated[int | None, typer.Option(help="Adapt only the last N of the 30 layers (cheaper).")] = None,
    max_val: Annotated[int, typer.Option(help="Validation examples scored before and after training.")] = 48,
    precision: Annotated[str, typer.Option(
        help="auto (bf16 autocast where the CPU has native bf16 and the first batch's loss matches fp32), "
             "fp32 or bf16.")] = "auto",
    checkpoint_every_s: Annotated[float, typer.Option(
        help="Seconds of training between resumable checkpoints.")] = 300.0,
    balance: Annotated[float, typer.Option(help="Repeat each training example (n of the commonest reply / n of its "
                                           "reply) ** BALANCE times, at most 8 (0: as labelled).")] = 0.0,
    init: Annotated[Path | None, typer.Option(
        help="Continue from this run's adapter (`letspi train llm --out`); same rank, alpha, layers, seed and "
             "split.")] = None,
    train_only: Annotated[list[Path] | None, typer.Option(
        "--train-only", help="Labels directory whose examples only train: the split is that of --data alone "
                             "(repeat for several).")] = None,
) -> None:
    """Fine-tune the embedded SmolLM2-135M with LoRA. Trains on physics-verified labels (LoRA on the packaged
    GGUF) and exports a llama.cpp adapter; use it with --llm llamacpp:smollm2-135m-letspi and
    LETSPI_LLM_ADAPTER=OUT/adapter.gguf."""
    _require_torch()
    from letspi_train.finetune.train import LoraTrainConfig, train_lora
    from letspi_train.learned.loop import checkpoint_step

    with user_errors(resumes=True) as tally, writer_lock(out, command_line()):
        cfg = LoraTrainConfig(epochs=epochs, lr=lr, rank=rank, alpha=alpha, batch_size=batch_size, seed=seed,
                              max_steps=max_steps, threads=threads, val_fraction=val_fraction,
                              layers=layers, max_val=max_val, precision=precision,  # type: ignore[arg-type]
                              checkpoint_every_s=checkpoint_every_s, balance=balance)
        examples, info = _llm_examples(data, scenarios, max_scenarios)
        extra: list[Any] = []
        if train_only:
            extra, extra_info = _llm_examples(list(train_only), None, None)
            info = {**info, "train_only": extra_info}
        with progress_bar() as bar:
            task = bar.add_task("fine-tuning", total=None)

            def progress(step: int, total: int, loss: float) -> None:
                bar.update(task, completed=step, total=total, description=f"fine-tuning (loss {loss:.3f})")
                if tally.total is None:  # stopped, it keeps the steps of its last checkpoint
                    tally.track(total, lambda: checkpoint_step(out))

            manifest = train_lora(examples, cfg, packaged_smollm2_path(), out, data_info=info,
                                  progress=progress, verify=verify, command=command_line(),
                                  init_dir=init, train_only=extra)
    t = manifest["training"]
    check = manifest.get("export_check") or {}
    console.print(f"adapter -> {out / 'adapter.gguf'} ({manifest['adapter']['bytes'] / 1e6:.1f} MB, "
                  f"{t['steps']} steps, {t['train_s']:.0f} s training, {t['precision']}); "
                  f"{manifest['data']['n_train']} train / "
                  f"{manifest['data']['n_val']} val examples; val loss {t['val_loss_before']:.3f} -> "
                  f"{t['val_loss_after']:.3f}; torch vs llama.cpp greedy agree on "
                  f"{check.get('agree', 0)}/{check.get('n', 0)} prompts")


@app.command("dpo")
def train_dpo_cmd(
    data: Annotated[list[Path], typer.Option("--data", help="Choice labels directories of `letspi train decide` "
                                             "(with the hindsight column), in the order `train llm` had them.")],
    init: Annotated[Path, typer.Option(help="The supervised adapter's directory (`letspi train llm --out`).")],
    out: AdapterOutOpt,
    beta: Annotated[float, typer.Option(help="DPO temperature (how far from the supervised adapter).")] = 0.1,
    lr: Annotated[float, typer.Option(help="Peak learning rate (AdamW, linear decay to 10 %).")] = 5e-5,
    epochs: Annotated[float, typer.Option(help="Passes over the training pairs.")] = 1.0,
    batch_size: Annotated[int, typer.Option(help="Pairs per optimiser step.")] = 4,
    margin: Annotated[float, typer.Option(help="A pair needs its presets' hindsight utilities this far apart.")] = 1.0,
    max_pairs: Annotated[int | None, typer.Option(help="At most this many training pairs (a seeded sample).")] = None,
    seed: SeedOpt = 0,
    threads: Annotated[int, typer.Option(help="torch CPU threads.")] = 2,
    checkpoint_every_s: Annotated[float, typer.Option(
        help="Seconds of training between resumable checkpoints.")] = 300.0,
) -> None:
    """One preference step after `letspi train llm`: DPO on pairs of presets ranked by their hindsight outcome
    (the best preset of a window against each one whose outcome is worse), from the supervised adapter."""
    _require_torch()
    from letspi_train.finetune.preference import DpoConfig, preference_pairs, train_dpo
    from letspi_train.learned.loop import checkpoint_step

    with user_errors(resumes=True) as tally, writer_lock(out, command_line()):
        cfg = DpoConfig(beta=beta, lr=lr, epochs=epochs, batch_size=batch_size, margin=margin, seed=seed,
                        threads=threads, checkpoint_every_s=checkpoint_every_s, max_pairs=max_pairs)
        examples, info = _llm_examples(data, None, None)
        pairs = preference_pairs(examples, data, margin=margin)
        if not pairs:
            raise ValueError(f"{', '.join(map(str, data))}: no window has presets whose hindsight differs by {margin}")
        with progress_bar() as bar:
            task = bar.add_task("preference step", total=None)

            def progress(step: int, total: int, loss: float) -> None:
                bar.update(task, completed=step, total=total, description=f"DPO (loss {loss:.3f})")
                if tally.total is None:
                    tally.track(total, lambda: checkpoint_step(out))

            manifest = train_dpo(pairs, cfg, packaged_smollm2_path(), init, out, data_info=info, progress=progress,
                                 command=command_line())
    t = manifest["training"]
    console.print(f"adapter -> {out / 'adapter.gguf'} ({t['steps']} steps, {t['train_s']:.0f} s); "
                  f"{manifest['data']['n_pairs_train']} train / {manifest['data']['n_pairs_val']} val pairs; held-out "
                  f"pairs ranked right {100 * t['val_pair_accuracy_before']:.1f} % -> "
                  f"{100 * t['val_pair_accuracy_after']:.1f} %")


@app.command("decide")
def train_decide(
    scenarios: ScenariosOpt,
    out: Annotated[Path, typer.Option(help="Output directory: pool/ (cached option outcomes), presets.json, "
                                      "risk_model.json, labels/<file>/ (for `letspi train llm`); rerun to resume.")],
    presets: Annotated[int, typer.Option(help="Presets to keep from the pool (the defaults included).")] = 6,
    consult_share: Annotated[float, typer.Option(
        help="Share of the training windows on which the risk gate consults the model (sets its threshold).")] = 0.15,
    keep_share: Annotated[float, typer.Option(
        help="Share of the windows the gate does not consult that become examples of keeping the defaults.")] = 0.1,
    refine_weight: Annotated[float, typer.Option(help="Weight (repetitions) of the refinement examples.")] = 2.0,
    sf_params: Annotated[Path | None, typer.Option(help="Fitted sf parameters (default: the shipped fit).")] = None,
    goals: Annotated[str, typer.Option(help="Goal source of the plans: learned or kinematic.")] = "learned",
    keep_presets: Annotated[Path | None, typer.Option(
        "--presets", help="Keep these presets (e.g. the shipped src/letspi/data/presets.json) instead of selecting "
                          "them: labels and teacher for them.")] = None,
    keep_gate: Annotated[Path | None, typer.Option(
        "--risk-model", help="Keep this risk gate (its scores and recommended threshold) instead of fitting one.")
    ] = None,
) -> None:
    """Train LetsPi's decision step on training traffic. Presets, the risk gate and decision-focused labels
    (hindsight: the recorded future decides which preset was best; never evaluation seeds)."""
    from letspi_train.finetune.decide_build import build_decision_data

    with user_errors(), writer_lock(out, command_line()):
        if goals not in ("learned", "kinematic"):
            raise ValueError("--goals must be learned or kinematic")
        if not 0.0 < consult_share <= 1.0:
            raise ValueError("--consult-share must be in (0, 1]")
        for path in scenarios:
            refuse_suite_traffic(path, read_scenario_meta(path))
        params, _ = load_sf_params(sf_params)
        goal_predictor = Builder(cache=None).goal_predictor(goals_config(goals))
        with progress_bar() as bar:
            task = bar.add_task("scoring the pool", total=None)
            summary = build_decision_data(scenarios, out, goal_predictor, params, goals=goals, n_presets=presets,
                                          consult_share=consult_share, keep_share=keep_share,
                                          refine_weight=refine_weight, command=command_line(),
                                          progress=lambda k: bar.advance(task, k), presets_file=keep_presets,
                                          risk_model_file=keep_gate)
    console.print(f"presets -> {out / 'presets.json'}: {', '.join(summary['presets'])}")
    gate = summary["gate"]
    console.print(f"risk gate -> {out / 'risk_model.json'}: threshold {gate['threshold']:.3f} consults "
                  f"{100 * gate['consult_share']:.1f} % of the training windows, {100 * gate['cv_recall']:.1f} % "
                  f"of those where the defaults collide (cross-validated AUC {gate['cv_auc']:.3f})")
    console.print(f"labels -> {out / 'labels'}: {summary['n_examples']} rows; option shares {summary['label_shares']}")
    console.print(f"teacher -> {out / 'teacher.json'} (the labels' expected-utility policy: letspi-fast --chooser "
                  "teacher --teacher FILE)")
