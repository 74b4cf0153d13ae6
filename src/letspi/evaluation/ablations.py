"""The paper's ablations as presets (§IV-E, Tables IV-V; docs/method.md), each written to ``DIR/ablations/<kind>/``;
memory-size and llm-combinations also write ``DIR/ablations/memory_size.json`` / ``llm_combinations.json`` (shapes in
``letspi.viz.report``). Each row's key says what it ran."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from letspi.assembly.build import Builder
from letspi.assembly.planners import BuiltPlanner, build_planner, resolve_planner
from letspi.assembly.resolve import Resolver
from letspi.evaluation.harness import EvaluationSettings, ProgressFactory, evaluate
from letspi.execution.ordered import RunnerConfig, RunStats
from letspi.fsutil import atomic_write_text
from letspi.llm.spec import default_concurrency
from letspi.method.memory import MemoryBank
from letspi.method.phases import collect
from letspi.metrics.aggregate import AggValue
from letspi.planners.llm import LLM_CACHE, MEMORY, MEMORY_KEY, MEMORY_SEED
from letspi.planners.options import PlannerOptions
from letspi.scenario.types import ScenarioBatch
from letspi.suggest import unknown

ABLATION_KINDS: tuple[str, ...] = ("reflection", "goal-adjustment", "few-shot", "memory-size", "llm-combinations")
MEMORY_FRACTIONS: tuple[float, ...] = (0.0, 0.01, 0.1, 0.5, 0.8)


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
    builder: Builder | None = None,
    concurrency: int | None = None,
    on_run: Callable[[str, RunStats], None] | None = None,
) -> dict[str, dict[str, AggValue]]:
    """Run one ablation preset; returns ``{row name: aggregated metrics}``. ``concurrency``: scenarios in
    flight for the LLM planners and the collection (None: each backend's default)."""
    if kind not in ABLATION_KINDS:
        raise ValueError(unknown("ablation", kind, ABLATION_KINDS))
    builder = builder or Builder(cache="default" if options.get(LLM_CACHE) else None)
    abl_root = Path(out_dir) / "ablations"
    target = abl_root / kind

    def run(planners: list[BuiltPlanner]) -> dict[str, dict[str, AggValue]]:
        out = evaluate(planners, batch, target, EvaluationSettings(
            scenarios_file=scenarios_file, progress_factory=progress_factory, concurrency=concurrency, on_run=on_run))
        return {p.name: out[p.name] for p in planners}

    def built(kind_: str, name: str, opts: PlannerOptions = options) -> BuiltPlanner:
        return build_planner(resolve_planner(kind_, opts), name, builder=builder)

    if kind == "reflection":
        return run([built("letspi-memory", "LetsPi_M"),
                    built("letspi-memory", "LetsPi_M w/o Ref", options.replace(max_iterations=0))])
    if kind == "goal-adjustment":
        return run([built("letspi-memory", "LetsPi_M"),
                    built("letspi-memory", "LetsPi_M w/o GA", options.replace(goal_adjustment=False))])
    if kind == "few-shot":
        return run([built("letspi-fast", "LetsPi_F"), built("letspi-fs", "FS (3 static examples)")])
    if kind == "memory-size":
        return _memory_size(options, fractions, abl_root, built, run)
    return _llm_combinations(options, collect_batch, combinations, abl_root, builder, built, run, concurrency)


def _memory_size(options: PlannerOptions, fractions: Sequence[float], abl_root: Path, built: Any,
                 run: Any) -> dict[str, dict[str, AggValue]]:
    memory = options.get(MEMORY)
    if memory is None:
        raise ValueError("memory-size ablation needs --memory (a bank from `letspi collect`)")
    planners = [built("letspi-fast", f"LetsPi_F mem {100 * f:g}%", options.replace(memory_fraction=f))
                for f in fractions]
    results = run(planners)
    key = options.get(MEMORY_KEY)
    with MemoryBank.open(memory, readonly=True) as bank:
        total = bank.count(config_key=key)
        sizes = [len(bank.sample_fraction(f, seed=options.get(MEMORY_SEED), config_key=key)) for f in fractions]
    points = [{"memory_size": 100.0 * f, "n_memories": n, "metrics": results[p.name]}
              for f, n, p in zip(fractions, sizes, planners, strict=True)]
    atomic_write_text(abl_root / "memory_size.json",
                      json.dumps({"total": 100, "n_total": total, "points": points}, indent=2, default=float))
    return results


def _llm_combinations(options: PlannerOptions, collect_batch: ScenarioBatch | None,
                      combinations: Sequence[tuple[str, str]], abl_root: Path, builder: Builder, built: Any,
                      run: Any, concurrency: int | None) -> dict[str, dict[str, AggValue]]:
    memory = options.get(MEMORY)
    if memory is None or collect_batch is None or not combinations:
        raise ValueError("llm-combinations needs --memory, collection scenarios and at least one --combo")
    planners: list[BuiltPlanner] = []
    rows = []
    for mem_spec, fast_spec in combinations:
        phase_config = Resolver(options.replace(llm=mem_spec)).memory_phase()
        phase, _ = builder.memory_phase(phase_config)
        n = concurrency if concurrency is not None else default_concurrency(phase_config.llm.spec)
        with MemoryBank.open(memory) as bank:
            collect(phase, collect_batch, bank, runner=RunnerConfig(concurrency=n))  # resumable
        name = f"memory {mem_spec} + fast {fast_spec}"
        fast_options = options.replace(fast_llm=fast_spec, memory_key=phase_config.key())
        planners.append(built("letspi-fast", name, fast_options))
        rows.append({"name": name, "physics": mem_spec, "fast": fast_spec, "collection_key": phase_config.key()})
    results = run(planners)
    combos = [{**row, "metrics": results[row["name"]]} for row in rows]
    atomic_write_text(abl_root / "llm_combinations.json", json.dumps({"combinations": combos}, indent=2, default=float))
    return results
