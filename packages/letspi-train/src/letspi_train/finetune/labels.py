"""Physics-verified training labels for the LLM (and the ``mlp`` regressor): hindsight search.

Per training scenario the eight answer values are searched (the fitted defaults, random candidates, then
rounds of local refinement around the best). Each candidate is planned as a planner plans it (against
predicted neighbours) and checked against the recorded future: hindsight, for training only. Rows
(``LABEL_COLUMNS``; format in docs/finetuning.md): ``propose`` (scene -> best candidate) and ``refine``
(scene + a rejected unsafe proposal + its safety report -> the nearest good safe candidate). Resumable:
chunks go to ``parts/part-NNNNN.parquet`` atomically and a rerun with the same settings skips them.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict

from letspi.analysis.options import random_candidates
from letspi.constants import DT_S
from letspi.fsutil import atomic_write, atomic_write_text, resume_directory
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS
from letspi.method.decide import defaults_vector, params_of
from letspi.method.reflection import Proposal, safety_report, simulate_proposal
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.goals import GoalPredictor
from letspi.physics.lanes import lane_width_m
from letspi.physics.neighbours import NeighbourPredictionMode, ground_truth_oracle, predict_neighbours
from letspi.physics.params import SocialForceParams
from letspi.physics.types import NeighbourPrediction
from letspi.safety.plan_check import SafetyCheck, check_recorded
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.types import ScenarioBatch

FORMAT = "letspi-llm-labels/1"
LABELS_FILE = "labels.parquet"
MANIFEST_FILE = "manifest.json"
PARTS_DIR = "parts"
PROPOSAL_COLUMNS = tuple(f"proposal_{f}" for f in NUMERIC_FIELDS)
LABEL_COLUMNS: tuple[str, ...] = (
    "scenario_index", "scenario_digest", "kind", *NUMERIC_FIELDS, *PROPOSAL_COLUMNS, "report_json",
    "label_safe", "label_score", "label_min_ttc_s", "label_min_gap_m", "label_progress_m",
)
_LOW = np.array([FIELD_RANGES[f][0] for f in NUMERIC_FIELDS])
_HIGH = np.array([FIELD_RANGES[f][1] for f in NUMERIC_FIELDS])
_SPAN = _HIGH - _LOW
_LANE = NUMERIC_FIELDS.index("lane_factor")
TTC_CAP_S = 6.0


class LabelSearch(BaseModel):
    """Search settings (recorded in the manifest; a resume with other settings is refused). Score, higher is
    better: unsafe ``-10 - 5 contact - 2 off-road - violations + margin`` (below every safe one); safe
    ``w_goal * min(progress / goal distance, 1) - w_overshoot * overshoot - w_lane * |lateral end error| / lane
    width - w_decel * peak braking / 8 - w_lat * peak |a_y| / 3 + w_margin * min(TTC, 6) / 6 - w_reg * distance
    to the defaults`` (the pull to the defaults makes the label unique, a learnable target)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    n_random: int = 48
    n_rounds: int = 2
    n_local: int = 24
    top_m: int = 4
    local_sigma: float = 0.12  # of each field's range, halved every round
    random_sigma: float = 0.2  # of each field's range, for the candidates around the defaults
    lane_snap_p: float = 0.7  # share of random candidates whose lane factor is exactly -1, 0 or +1
    neighbours: NeighbourPredictionMode = NeighbourPredictionMode.IDM
    ttc_s: float = 1.5
    min_dist_m: float = 2.0
    max_decel_mps2: float = 8.0
    w_goal: float = 3.0
    w_overshoot: float = 1.0
    w_lane: float = 0.5
    w_decel: float = 0.3
    w_lat: float = 0.3
    w_margin: float = 0.3
    w_reg: float = 0.6
    refine_tolerance: float = 0.5
    chunk: int = 16


def _repeat(pred: NeighbourPrediction, c: int) -> NeighbourPrediction:
    return pred.repeat(c)


@dataclass(frozen=True)
class CandidateResults:
    """Per candidate (B, C): score, safe, and measured facts of its rollout against the recorded future."""

    score: np.ndarray
    safe: np.ndarray
    min_ttc_s: np.ndarray
    min_gap_m: np.ndarray
    progress_m: np.ndarray
    collision: np.ndarray


def evaluate_candidates(
    batch: ScenarioBatch,
    values: np.ndarray,
    base_goals_xy_m: np.ndarray,
    prediction: NeighbourPrediction,
    defaults: np.ndarray,
    r_col_m: float,
    search: LabelSearch,
) -> CandidateResults:
    """Plan every candidate as a planner would and score it against the recorded future, in one call: batch
    (B scenarios WITH their future), values (B, C, 8), base_goals_xy_m (B, 2), prediction (B, N, F, ...),
    defaults (8,) the regularisation centre."""
    b, c, _ = values.shape
    rep = np.repeat(np.arange(b), c)
    big = batch.take(rep)
    flat = values.reshape(b * c, -1)
    plan = simulate_proposal(big, params_of(flat, r_col_m), flat[:, 6], flat[:, 7], base_goals_xy_m[rep],
                             _repeat(prediction, c))
    check = check_recorded(big, plan.xy_m, plan.vxy_mps)
    return _score(big, plan.xy_m, plan.vxy_mps, base_goals_xy_m[rep], check, flat, defaults, search, (b, c))


def _score(big: ScenarioBatch, xy: np.ndarray, vxy: np.ndarray, goals: np.ndarray, check: SafetyCheck,
           flat: np.ndarray, defaults: np.ndarray, s: LabelSearch, shape: tuple[int, int]) -> CandidateResults:
    x0 = big.ego_xy0_m.astype(np.float64)
    v0 = np.nan_to_num(big.ego_vxy0_mps.astype(np.float64))
    to_goal = goals - x0
    goal_dist = np.maximum(np.hypot(to_goal[:, 0], to_goal[:, 1]), 1.0)
    progress = ((xy[:, -1] - x0) * to_goal).sum(axis=1) / goal_dist
    frac = progress / goal_dist
    lane_w = lane_width_m(big.marking_y_m)
    lat_err = np.abs(xy[:, -1, 1] - goals[:, 1]) / np.where(np.isfinite(lane_w) & (lane_w > 0), lane_w, 3.75)
    v = np.concatenate([v0[:, None], vxy], axis=1)
    acc = np.diff(v, axis=1) / DT_S  # (R, F, 2)
    decel = np.clip(-acc[..., 0].min(axis=1), 0.0, None)
    lat = np.abs(acc[..., 1]).max(axis=1)
    ttc = np.minimum(np.minimum(check.min_ttc_s, check.min_rear_ttc_s), TTC_CAP_S)
    gap = np.minimum(check.min_path_gap_m, 50.0)
    violations = (check.collision.astype(int) + check.off_road + (check.min_ttc_s < s.ttc_s)
                  + (check.min_rear_ttc_s < s.ttc_s) + (check.min_path_gap_m < s.min_dist_m)
                  + (decel > s.max_decel_mps2))
    safe = violations == 0
    reg = np.sqrt((((flat - defaults) / _SPAN) ** 2).mean(axis=1))
    good = (s.w_goal * np.clip(frac, 0.0, 1.0) - s.w_overshoot * np.clip(frac - 1.0, 0.0, None)
            - s.w_lane * lat_err - s.w_decel * decel / 8.0 - s.w_lat * lat / 3.0
            + s.w_margin * ttc / TTC_CAP_S - s.w_reg * reg)
    bad = -10.0 - 5.0 * check.collision - 2.0 * check.off_road - violations + ttc / TTC_CAP_S + 0.01 * gap
    score = np.where(safe, good, bad)
    return CandidateResults(
        score=score.reshape(shape), safe=safe.reshape(shape), min_ttc_s=ttc.reshape(shape),
        min_gap_m=gap.reshape(shape), progress_m=progress.reshape(shape),
        collision=check.collision.reshape(shape),
    )


def _local(rng: np.random.Generator, centres: np.ndarray, n: int, sigma: float) -> np.ndarray:
    """(n, 8) perturbations around ``centres`` (M, 8), cycling through them."""
    pick = centres[np.arange(n) % len(centres)]
    out = pick + rng.normal(0.0, sigma, pick.shape) * _SPAN
    keep_lane = rng.random(n) < 0.5  # half keep the lane decision of their centre
    out[:, _LANE] = np.where(keep_lane, pick[:, _LANE], out[:, _LANE])
    return np.clip(out, _LOW, _HIGH)


def _order(res: CandidateResults) -> np.ndarray:
    """(B, C) candidate order per scenario, best first (safe ones first by construction of the score)."""
    return np.argsort(-res.score, axis=1, kind="stable")


def search_chunk(
    batch: ScenarioBatch,
    indices: np.ndarray,
    goal_predictor: GoalPredictor,
    params: SocialForceParams,
    search: LabelSearch,
    seed: int,
) -> tuple[np.ndarray, CandidateResults, np.ndarray, NeighbourPrediction]:
    """Search B scenarios (``batch`` with the future; ``indices`` (B,) their file rows seed their generators, so
    results do not depend on the chunking): candidates (B, C, 8), results (B, C), goals (B, 2), the prediction."""
    history = batch.history()
    goals = goal_predictor.predict_goals(history).top.astype(np.float64)
    pred = predict_neighbours(history, search.neighbours)
    defaults = defaults_vector(params)
    r_col = float(params.r_col_m)
    rngs = [np.random.default_rng([seed, int(i)]) for i in indices]
    cands = np.stack([random_candidates(r, search.n_random, defaults, sigma=search.random_sigma,
                                        lane_snap_p=search.lane_snap_p) for r in rngs])
    res = evaluate_candidates(batch, cands, goals, pred, defaults, r_col, search)
    for rnd in range(search.n_rounds):
        best = np.take_along_axis(cands, _order(res)[:, :search.top_m, None], axis=1)
        sigma = search.local_sigma * 0.5 ** rnd
        new = np.stack([_local(r, best[k], search.n_local, sigma) for k, r in enumerate(rngs)])
        new_res = evaluate_candidates(batch, new, goals, pred, defaults, r_col, search)
        cands = np.concatenate([cands, new], axis=1)
        res = CandidateResults(*(np.concatenate([getattr(res, f), getattr(new_res, f)], axis=1)
                                 for f in CandidateResults.__dataclass_fields__))
    return cands, res, goals, pred


def _report_json(scenario: ScenarioBatch, proposal: np.ndarray, base_goal: np.ndarray, pred: NeighbourPrediction,
                 r_col_m: float, search: LabelSearch, failed: dict[str, bool]) -> str:
    """The reflection module's report of ``proposal``'s plan against the recorded neighbours."""
    plan = simulate_proposal(scenario, params_of(proposal[None], r_col_m), proposal[None, 6], proposal[None, 7],
                             base_goal[None], pred)
    th = ReflectionThresholds(ttc_s=search.ttc_s, min_dist_m=search.min_dist_m,
                              max_decel_mps2=search.max_decel_mps2)
    recorded = ground_truth_oracle(scenario)
    report = safety_report(scenario, plan.xy_m, plan.vxy_mps, recorded, th)[0]
    prop = Proposal(params=params_of(proposal[None], r_col_m).row(0), lon_factor=float(proposal[6]),
                    lane_factor=float(proposal[7]))
    m = report.metrics
    return json.dumps({
        "min_ttc_s": _finite(m["min_ttc_s"]), "min_rear_ttc_s": _finite(m["min_rear_ttc_s"]),
        "min_path_gap_m": _finite(m["min_path_gap_m"]), "min_box_gap_m": _finite(m["min_box_gap_m"]),
        "collision": bool(m["collision"]), "off_road": bool(m["off_road"]),
        "max_decel_mps2": _finite(m["max_decel_mps2"]),
        "failed": sorted(k for k, v in failed.items() if v) or [v.metric for v in report.violations],
        "violations": [v.metric for v in report.violations],
        "text": report.to_text(prop),
    }, sort_keys=True)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _failed(res: CandidateResults, i: int, j: int, s: LabelSearch) -> dict[str, bool]:
    return {"contact": bool(res.collision[i, j]), "ttc": bool(res.min_ttc_s[i, j] < s.ttc_s),
            "in_path_gap": bool(res.min_gap_m[i, j] < s.min_dist_m)}


def label_rows(
    batch: ScenarioBatch,
    indices: np.ndarray,
    goal_predictor: GoalPredictor,
    params: SocialForceParams,
    search: LabelSearch,
    seed: int,
) -> list[dict[str, Any]]:
    """Label rows (``LABEL_COLUMNS``) of the scenarios ``batch`` (rows ``indices`` of their file)."""
    cands, res, goals, pred = search_chunk(batch, indices, goal_predictor, params, search, seed)
    digests = scenario_digests(batch)
    defaults = defaults_vector(params)
    r_col = float(params.r_col_m)
    order = _order(res)
    rows: list[dict[str, Any]] = []
    for i in range(len(batch)):
        best = int(order[i, 0])
        rng = np.random.default_rng([seed, int(indices[i]), 1])

        def row(kind: str, target: int, proposal: np.ndarray | None, report: str, i: int = i) -> dict[str, Any]:
            out: dict[str, Any] = {"scenario_index": int(indices[i]), "scenario_digest": str(digests[i]),
                                   "kind": kind}
            out.update({f: float(cands[i, target, k]) for k, f in enumerate(NUMERIC_FIELDS)})
            out.update({p: float(proposal[k]) if proposal is not None else float("nan")
                        for k, p in enumerate(PROPOSAL_COLUMNS)})
            out.update(report_json=report, label_safe=bool(res.safe[i, target]),
                       label_score=float(res.score[i, target]), label_min_ttc_s=float(res.min_ttc_s[i, target]),
                       label_min_gap_m=float(res.min_gap_m[i, target]),
                       label_progress_m=float(res.progress_m[i, target]))
            return out

        rows.append(row("propose", best, None, ""))
        if not res.safe[i, best]:
            continue  # no safe candidate: nothing to refine towards
        rejected = [0] if not res.safe[i, 0] else []  # candidate 0 = the fitted defaults
        unsafe_random = [j for j in range(1, search.n_random) if not res.safe[i, j]]
        if unsafe_random:
            rejected.append(int(rng.choice(unsafe_random)))
        good = np.flatnonzero(res.safe[i] & (res.score[i] >= res.score[i, best] - search.refine_tolerance))
        for j in rejected:
            dist = np.sqrt((((cands[i, good] - cands[i, j]) / _SPAN) ** 2).sum(axis=1))
            target = int(good[np.argmin(dist)])
            report = _report_json(batch.take([i]), cands[i, j], goals[i], _take_pred(pred, i), r_col, search,
                                  _failed(res, i, j, search))
            rows.append(row("refine", target, cands[i, j], report))
    del defaults
    return rows


def _take_pred(pred: NeighbourPrediction, i: int) -> NeighbourPrediction:
    return pred.take(slice(i, i + 1))


def frame_of(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Rows -> a frame with exactly ``LABEL_COLUMNS`` and the format's dtypes."""
    df = pd.DataFrame(rows, columns=list(LABEL_COLUMNS))
    df["scenario_index"] = df["scenario_index"].astype("int64")
    for col in ("scenario_digest", "kind", "report_json"):
        df[col] = df[col].astype(str)
    for col in (*NUMERIC_FIELDS, *PROPOSAL_COLUMNS, "label_score", "label_min_ttc_s", "label_min_gap_m",
                "label_progress_m"):
        df[col] = df[col].astype("float64")
    df["label_safe"] = df["label_safe"].astype(bool)
    return df


def sf_params_sha256(params: SocialForceParams) -> str:
    return hashlib.sha256(json.dumps(params.as_dict(), sort_keys=True).encode()).hexdigest()


@dataclass
class LabelRun:
    """One ``train llm-data`` run into ``out`` (resumable; see the module docstring)."""

    scenarios_path: Path
    batch: ScenarioBatch
    out: Path
    goal_predictor: GoalPredictor
    params: SocialForceParams
    search: LabelSearch
    seed: int
    command: str = ""
    consolidate_s: float = 60.0

    def _settings(self) -> dict[str, Any]:
        return {"format": FORMAT, "dataset_digest": self.dataset_digest, "seed": self.seed,
                "search": self.search.model_dump(mode="json"), "sf_params_sha256": sf_params_sha256(self.params)}

    @property
    def dataset_digest(self) -> str:
        if not hasattr(self, "_digest"):
            self._digest = dataset_digest(scenario_digests(self.batch))
        return self._digest

    def run(self, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
        """Label every scenario; returns the manifest. Finished parts of an earlier run are reused."""
        parts, _ = resume_directory(self.out, self._settings(), what="labels", instead="use another --out",
                                    parts_dir=PARTS_DIR)
        t0 = time.perf_counter()
        elapsed_before = float(json.loads((self.out / MANIFEST_FILE).read_text()).get("elapsed_s", 0.0)) \
            if (self.out / MANIFEST_FILE).exists() else 0.0
        last = time.perf_counter()
        n = len(self.batch)
        step = self.search.chunk
        for start in range(0, n, step):
            part = parts / f"part-{start:06d}.parquet"
            stop = min(start + step, n)
            if not part.exists():
                idx = np.arange(start, stop)
                df = frame_of(label_rows(self.batch.take(idx), idx, self.goal_predictor, self.params,
                                         self.search, self.seed))
                _write_parquet(part, df)
                if time.perf_counter() - last > self.consolidate_s:
                    self._consolidate(elapsed_before + time.perf_counter() - t0, complete=False)
                    last = time.perf_counter()
            if progress is not None:
                progress(stop - start)
        return self._consolidate(elapsed_before + time.perf_counter() - t0, complete=True)

    def _consolidate(self, elapsed_s: float, complete: bool) -> dict[str, Any]:
        files = sorted((self.out / PARTS_DIR).glob("part-*.parquet"))
        df = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True) if files else frame_of([])
        _write_parquet(self.out / LABELS_FILE, df)
        n_scen = int(df["scenario_index"].nunique())
        manifest = {
            "format": FORMAT, "scenarios_path": str(self.scenarios_path), "dataset_digest": self.dataset_digest,
            "n_scenarios": n_scen, "n_propose": int((df["kind"] == "propose").sum()),
            "n_refine": int((df["kind"] == "refine").sum()), "seed": self.seed,
            "search": self.search.model_dump(mode="json"), "sf_params": self.params.as_dict(),
            "sf_params_sha256": sf_params_sha256(self.params), "command": self.command,
            "elapsed_s": elapsed_s, "scenarios_per_s": n_scen / elapsed_s if elapsed_s > 0 else None,
            "label_safe_share": float(df.loc[df["kind"] == "propose", "label_safe"].mean()) if len(df) else None,
            "labels_sha256": hashlib.sha256((self.out / LABELS_FILE).read_bytes()).hexdigest(),
            "complete": complete, "n_scenarios_total": len(self.batch),
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        atomic_write_text(self.out / MANIFEST_FILE, json.dumps(manifest, indent=2) + "\n")
        return manifest


def _write_parquet(path: Path, df: pd.DataFrame) -> None:
    def write(tmp: Path) -> None:
        df.to_parquet(tmp, index=False)

    atomic_write(path, write)


def load_labels(directory: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """``labels.parquet`` and ``manifest.json`` of a labels directory (clear error when absent or foreign)."""
    d = Path(directory)
    mfile, lfile = d / MANIFEST_FILE, d / LABELS_FILE
    if not mfile.is_file() or not lfile.is_file():
        raise FileNotFoundError(f"{d}: no labels here (expected {LABELS_FILE} and {MANIFEST_FILE}; "
                                "create them with `letspi train llm-data`)")
    manifest = json.loads(mfile.read_text())
    if manifest.get("format") != FORMAT:
        raise ValueError(f"{mfile}: format {manifest.get('format')!r}, expected {FORMAT!r}")
    df = pd.read_parquet(lfile)
    missing = [c for c in LABEL_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{lfile}: missing column(s) {missing}")
    return df, manifest
