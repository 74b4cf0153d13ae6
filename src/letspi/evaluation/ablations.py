"""The paper's ablations as presets (§IV-E, Tables IV-V), each a resumable evaluation directory.

``DIR/ablations/<kind>/`` holds ``metrics.json`` / ``metrics.md`` / per-scenario results like any
evaluation; the memory-size and LLM-combination presets also write
``DIR/ablations/memory_size.json`` and ``DIR/ablations/llm_combinations.json`` (shapes in
``letspi.viz.report``), which ``letspi report DIR`` plots.

Kinds:
    reflection       letspi-memory with and without reflection (0 refinements)
    goal-adjustment  letspi-memory with and without LLM goal adjustment
    few-shot         letspi-fast (retrieved memories) vs letspi-fs (three static examples)
    memory-size      letspi-fast with 0/1/10/50/80 % of the collected memory (nested subsets)
    llm-combinations (memory model, fast model) pairs: collect with the first, plan with the second
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from letspi.evaluation.harness import evaluate
from letspi.metrics.aggregate import AggValue
from letspi.planners.base import Planner
from letspi.registry.factory import PlannerOptions, make_planners
from letspi.scenario.types import ScenarioBatch

ABLATION_KINDS: tuple[str, ...] = ("reflection", "goal-adjustment", "few-shot", "memory-size", "llm-combinations")
MEMORY_FRACTIONS: tuple[float, ...] = (0.0, 0.01, 0.1, 0.5, 0.8)

ProgressFactory = Callable[[str, int], Callable[[int], None]]


def _renamed(planner: Planner, name: str) -> Planner:
    planner.name = name
    return planner


def run_ablation(
    kind: str,
    batch: ScenarioBatch,
    out_dir: Path,
    options: PlannerOptions,
    *,
    scenarios_file: str = "",
    collect_batch: ScenarioBatch | None = None,
    combinations: Sequence[tuple[str, str]] = (),
    fractions: Sequence[float] = MEMORY_FRACTIONS,
    progress_factory: ProgressFactory | None = None,
) -> dict[str, dict[str, AggValue]]:
    """Run one ablation preset; returns ``{row name: aggregated metrics}``."""
    if kind not in ABLATION_KINDS:
        raise ValueError(f"unknown ablation {kind!r}; available: {', '.join(ABLATION_KINDS)}")
    abl_root = Path(out_dir) / "ablations"
    target = abl_root / kind

    def run(planners: list[Planner]) -> dict[str, dict[str, AggValue]]:
        return evaluate(planners, batch, target, scenarios_file=scenarios_file, progress_factory=progress_factory)

    if kind == "reflection":
        full = make_planners(["letspi-memory"], options)[0]
        none = make_planners(["letspi-memory"], replace(options, max_iterations=0))[0]
        return run([_renamed(full, "LetsPi_M"), _renamed(none, "LetsPi_M w/o Ref")])
    if kind == "goal-adjustment":
        full = make_planners(["letspi-memory"], options)[0]
        no_ga = make_planners(["letspi-memory"], replace(options, goal_adjustment=False))[0]
        return run([_renamed(full, "LetsPi_M"), _renamed(no_ga, "LetsPi_M w/o GA")])
    if kind == "few-shot":
        fast, fs = make_planners(["letspi-fast", "letspi-fs"], options)
        return run([_renamed(fast, "LetsPi_F"), _renamed(fs, "FS (3 static examples)")])
    if kind == "memory-size":
        return _memory_size(batch, abl_root, options, fractions, run)
    return _llm_combinations(batch, abl_root, options, collect_batch, combinations, run)


def _memory_size(batch: ScenarioBatch, abl_root: Path, options: PlannerOptions, fractions: Sequence[float],
                 run: Callable[[list[Planner]], dict[str, dict[str, AggValue]]]) -> dict[str, dict[str, AggValue]]:
    from letspi.core.memory import MemoryBank
    from letspi.planners.llm import LetsPiFastPlanner

    if options.memory is None:
        raise ValueError("memory-size ablation needs --memory (a bank from `letspi collect`)")
    with MemoryBank.open(options.memory, readonly=True) as bank:
        total = bank.count(config_key=options.memory_key)
        subsets = {f: bank.sample_fraction(f, seed=0, config_key=options.memory_key).ids for f in fractions}
    planners: list[Planner] = []
    for f in fractions:
        p = make_planners(["letspi-fast"], options)[0]
        assert isinstance(p, LetsPiFastPlanner) and p.phase.retriever is not None
        p.phase.retriever.subset_ids = subsets[f]
        planners.append(_renamed(p, f"LetsPi_F mem {100 * f:g}%"))
    results = run(planners)
    points = [{"memory_size": 100.0 * f, "n_memories": len(subsets[f]), "metrics": results[p.name]}
              for f, p in zip(fractions, planners, strict=True)]
    (abl_root / "memory_size.json").write_text(json.dumps({"total": 100, "n_total": total, "points": points},
                                                          indent=2))
    return results


def _llm_combinations(batch: ScenarioBatch, abl_root: Path, options: PlannerOptions,
                      collect_batch: ScenarioBatch | None, combinations: Sequence[tuple[str, str]],
                      run: Callable[[list[Planner]], dict[str, dict[str, AggValue]]]) -> dict[str, dict[str, AggValue]]:
    from letspi.core.memory import MemoryBank
    from letspi.core.phases import MemoryPhase, collect
    from letspi.core.thresholds import ReflectionThresholds
    from letspi.registry.factory import make_advisor, make_goal_predictor
    from letspi.planners.llm import LetsPiFastPlanner
    from letspi.planners.sf_params import load_sf_params

    if options.memory is None or collect_batch is None or not combinations:
        raise ValueError("llm-combinations needs --memory, collection scenarios and at least one --combo")
    r_col = load_sf_params(options.sf_params_file)[0].r_col_m
    planners: list[Planner] = []
    rows = []
    for mem_spec, fast_spec in combinations:
        phase = MemoryPhase(make_advisor(mem_spec, options.llm_cache, options.sf_params_file),
                            make_goal_predictor(options.goals), r_col,
                            thresholds=ReflectionThresholds(max_iterations=options.max_iterations))
        with MemoryBank.open(options.memory) as bank:
            collect(phase, collect_batch, bank)  # resumable: done scenarios are skipped
        p = make_planners(["letspi-fast"], replace(options, fast_llm=fast_spec))[0]
        assert isinstance(p, LetsPiFastPlanner) and p.phase.retriever is not None
        p.phase.retriever.config_key = phase.config_key
        name = f"memory {mem_spec} + fast {fast_spec}"
        planners.append(_renamed(p, name))
        rows.append({"name": name, "physics": mem_spec, "fast": fast_spec})
    results = run(planners)
    combos = [{**row, "metrics": results[row["name"]]} for row in rows]
    (abl_root / "llm_combinations.json").write_text(json.dumps({"combinations": combos}, indent=2))
    return results
