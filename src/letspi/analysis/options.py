"""A fixed table of candidate answers scored on every window: what each would have done, and what a planner
could have known about it (the expensive part of headroom and labels; cached and resumable).

``score_options`` plans every option of an ``OptionTable`` as the LLM planners plan an answer and records
hindsight outcomes (as the evaluation computes them; training and analysis only) and, optionally, the
plan-time checks. ``OptionRun`` stores a scenario file's outcomes in atomic chunks
(``parts/part-NNNNNN.npz``) consolidated into ``outcomes.npz``; a rerun skips chunks, refuses other settings.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from letspi.arrays import Rows
from letspi.fsutil import atomic_write, atomic_write_text, resume_directory
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS
from letspi.method.decide import DEFAULT_NAME, OptionTable, check_options, defaults_vector, plan_options
from letspi.method.thresholds import ReflectionThresholds
from letspi.metrics.compute import compute_outcomes
from letspi.physics.goals import GoalPredictor
from letspi.physics.neighbours import NeighbourPredictionMode, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.safety.adverse import AdverseSettings
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.types import ScenarioBatch

FORMAT = "letspi-option-outcomes/1"
OUTCOMES_FILE = "outcomes.npz"
MANIFEST_FILE = "manifest.json"


_LOW = np.array([FIELD_RANGES[f][0] for f in NUMERIC_FIELDS])
_HIGH = np.array([FIELD_RANGES[f][1] for f in NUMERIC_FIELDS])
_LANE = NUMERIC_FIELDS.index("lane_factor")


def random_candidates(rng: np.random.Generator, n: int, defaults: np.ndarray, *, sigma: float = 0.2,
                      lane_snap_p: float = 0.7) -> np.ndarray:
    """(n, 8): the defaults first, then half uniform over the fields' ranges, half normal around the defaults
    (``sigma`` of each range); a share ``lane_snap_p`` of the lane factors is rounded to -1, 0 or +1."""
    span = _HIGH - _LOW
    n_uniform = (n - 1) // 2
    uniform = _LOW + rng.random((n_uniform, len(_LOW))) * span
    near = defaults + rng.normal(0.0, sigma, (n - 1 - n_uniform, len(_LOW))) * span
    out = np.clip(np.concatenate([defaults[None], uniform, near]), _LOW, _HIGH)
    snap = rng.random(n) < lane_snap_p
    out[1:, _LANE] = np.where(snap[1:], np.round(out[1:, _LANE]), out[1:, _LANE])
    return out


def random_option_table(params: SocialForceParams, n: int, seed: int) -> OptionTable:
    """The fitted defaults (neutral goal) and ``n - 1`` random answers (the label search's first round)."""
    if n < 1:
        raise ValueError("an option table needs at least the defaults (n >= 1)")
    values = random_candidates(np.random.default_rng(seed), n, defaults_vector(params))
    return OptionTable((DEFAULT_NAME, *(f"r{k:03d}" for k in range(1, n))), values)


@dataclass(frozen=True)
class OptionOutcomes(Rows):
    """Per window and option, (B, C) each. Hindsight: collision, at_fault, success, min_ttc_s, progress_m (the
    plan's end x [m]). Plan time (scored with ``checks``, else all False and A = 0): predicted_safe,
    adverse_failed (B, C, A), adverse_applies (B, A)."""

    collision: np.ndarray
    at_fault: np.ndarray
    success: np.ndarray
    min_ttc_s: np.ndarray
    progress_m: np.ndarray
    predicted_safe: np.ndarray
    adverse_failed: np.ndarray
    adverse_applies: np.ndarray

    @classmethod
    def concat(cls, parts: list[OptionOutcomes]) -> OptionOutcomes:
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    def take_options(self, columns: np.ndarray | list[int]) -> OptionOutcomes:
        """The outcomes of some options (columns of the option axis)."""
        cols = np.asarray(columns, dtype=np.int64)
        return replace(self, **{f.name: getattr(self, f.name)[:, cols] for f in fields(self)
                                if f.name != "adverse_applies"})

    def with_options(self, other: OptionOutcomes) -> OptionOutcomes:
        """These options followed by ``other``'s on the same windows (``other`` without checks: unchecked)."""
        a = self.adverse_failed.shape[2]
        failed = other.adverse_failed if other.adverse_failed.shape[2] == a else np.zeros(
            (*other.collision.shape, a), dtype=bool)
        extra = replace(other, adverse_failed=failed)
        return replace(self, **{f.name: np.concatenate([getattr(self, f.name), getattr(extra, f.name)], axis=1)
                                for f in fields(self) if f.name != "adverse_applies"})

    def arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def score_options(
    batch: ScenarioBatch,
    table: OptionTable,
    goal_predictor: GoalPredictor,
    params: SocialForceParams,
    *,
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM,
    checks: bool = False,
    thresholds: ReflectionThresholds | None = None,
    adverse: AdverseSettings | None = None,
) -> OptionOutcomes:
    """Score every option of ``table`` on the B windows of ``batch`` (with its future): plans see the history,
    hindsight columns the recorded future. ``checks``: also the plan-time checks (``check_options``)."""
    if not batch.has_future:
        raise ValueError("score_options needs windows with their recorded future (hindsight)")
    hist = batch.history()
    b, c = len(batch), len(table)
    goals = goal_predictor.predict_goals(hist).top.astype(np.float64)
    pred = predict_neighbours(hist, neighbours)
    if checks:
        chk = check_options(hist, goals, pred, table, float(params.r_col_m), thresholds, adverse)
        xy, vxy = chk.xy_m.reshape(b * c, -1, 2), chk.vxy_mps.reshape(b * c, -1, 2)
        predicted_safe, failed = chk.predicted_safe, chk.adverse_failed
        applies = np.zeros((b, failed.shape[2]), dtype=bool)  # kept for the stored format
    else:
        xy, vxy, _ = plan_options(hist, table.values, goals, pred, float(params.r_col_m))
        predicted_safe, failed, applies = (np.zeros((b, c), dtype=bool), np.zeros((b, c, 0), dtype=bool),
                                           np.zeros((b, 0), dtype=bool))
    out = compute_outcomes(batch.take(np.repeat(np.arange(b), c)), xy, vxy)

    def grid(a: np.ndarray) -> np.ndarray:
        return np.asarray(a).reshape(b, c)

    return OptionOutcomes(
        collision=grid(out.collision), at_fault=grid(out.collision_at_fault), success=grid(out.success),
        min_ttc_s=grid(out.min_ttc_s), progress_m=grid(out.progress_m), predicted_safe=predicted_safe,
        adverse_failed=failed, adverse_applies=applies,
    )


class OptionRunSettings(BaseModel):
    """What a stored option run depends on (a resume with other settings is refused)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    format: str = FORMAT
    dataset_digest: str
    table_sha256: str
    sf_params: dict[str, float]
    goals: str
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    checks: bool = False
    thresholds: ReflectionThresholds = ReflectionThresholds()
    adverse: AdverseSettings = AdverseSettings()
    chunk: int = 64


@dataclass
class OptionRun:
    """The outcomes of ``table`` on every window of a scenario file, stored under ``out`` (resumable)."""

    batch: ScenarioBatch
    table: OptionTable
    out: Path
    goal_predictor: GoalPredictor
    params: SocialForceParams
    settings: OptionRunSettings

    @classmethod
    def create(cls, batch: ScenarioBatch, table: OptionTable, out: Path, goal_predictor: GoalPredictor,
               params: SocialForceParams, *, goals: str, checks: bool = False,
               thresholds: ReflectionThresholds | None = None, adverse: AdverseSettings | None = None,
               chunk: int = 64) -> OptionRun:
        settings = OptionRunSettings(
            dataset_digest=dataset_digest(scenario_digests(batch)), table_sha256=table.sha256(),
            sf_params=params.as_dict(), goals=goals, checks=checks, thresholds=thresholds or ReflectionThresholds(),
            adverse=adverse or AdverseSettings(), chunk=chunk)
        return cls(batch, table, Path(out), goal_predictor, params, settings)

    def run(self, progress: Callable[[int], None] | None = None) -> OptionOutcomes:
        """Score every window (finished chunks of an earlier run are reused) and consolidate."""
        wanted = self.settings.model_dump(mode="json")
        parts, fresh = resume_directory(self.out, wanted, what="option outcomes", instead="use another directory")
        if fresh:
            atomic_write_text(self.out / "options.json", json.dumps(self.table.to_json(), indent=1) + "\n")
        t0 = time.perf_counter()
        n, step = len(self.batch), self.settings.chunk
        for start in range(0, n, step):
            part = parts / f"part-{start:06d}.npz"
            stop = min(start + step, n)
            if not part.exists():
                res = score_options(self.batch.take(np.arange(start, stop)), self.table, self.goal_predictor,
                                    self.params, neighbours=self.settings.neighbours, checks=self.settings.checks,
                                    thresholds=self.settings.thresholds, adverse=self.settings.adverse)
                _save_npz(part, res.arrays())
            if progress is not None:
                progress(stop - start)
        outcomes = OptionOutcomes.concat([load_outcomes_file(parts / f"part-{s:06d}.npz") for s in range(0, n, step)])
        _save_npz(self.out / OUTCOMES_FILE, outcomes.arrays())
        manifest = {"format": FORMAT, "settings": wanted, "n_windows": n, "n_options": len(self.table),
                    "options": list(self.table.names), "elapsed_s_this_run": time.perf_counter() - t0,
                    "scenario_ids_sha256": hashlib.sha256("\n".join(map(str, self.batch.scenario_id)).encode()
                                                          ).hexdigest()}
        atomic_write_text(self.out / MANIFEST_FILE, json.dumps(manifest, indent=2) + "\n")
        return outcomes


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, allow_pickle=False, **arrays)

    atomic_write(path, write)


def load_outcomes_file(path: Path) -> OptionOutcomes:
    with np.load(path) as data:
        return OptionOutcomes(**{f.name: data[f.name] for f in fields(OptionOutcomes)})


def load_option_run(directory: Path) -> tuple[OptionTable, OptionOutcomes, dict[str, Any]]:
    """(table, outcomes, manifest) of a finished ``OptionRun`` directory."""
    d = Path(directory)
    if not (d / OUTCOMES_FILE).is_file() or not (d / MANIFEST_FILE).is_file():
        raise FileNotFoundError(f"{d}: no finished option outcomes here (expected {OUTCOMES_FILE}, {MANIFEST_FILE})")
    table = OptionTable.from_json(json.loads((d / "options.json").read_text()))
    return table, load_outcomes_file(d / OUTCOMES_FILE), json.loads((d / MANIFEST_FILE).read_text())
