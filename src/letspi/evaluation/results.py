"""An evaluation directory (layout in docs/evaluation.md): the keys that guard it and the part files holding its rows.

A directory holds one dataset under one metrics configuration and mode, and one configuration per planner label;
anything else is refused naming what differs. Rows are keyed by scenario digest, so a rerun resumes. Files are
written atomically; a planner that stored nothing leaves nothing."""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from letspi.assembly.planners import BuiltPlanner
from letspi.constants import N_FUTURE
from letspi.execution.ordered import RunStatus
from letspi.fsutil import atomic_write, atomic_write_text, remove_stale_temporaries
from letspi.keyed import diff, key_of
from letspi.metrics.config import MetricsConfig
from letspi.metrics.uncertainty import GROUP_COLUMN
from letspi.scenario.identity import dataset_digest, scenario_digests
from letspi.scenario.types import ScenarioBatch
from letspi.simulation.config import EvaluationMode

#: (advance by k scenarios, the concurrent runner's status or None)
ProgressCallback = Callable[[int, RunStatus | None], None]

RUN_FORMAT: Final = 2
PLAN_COLUMNS: Final = ("plan_xy_m", "plan_vxy_mps", "plan_goal_xy_m")
#: prefix of the large closed-loop array columns (replan plans, simulated neighbours); read only ``with_plans``
TRAJECTORY_PREFIX: Final = "cl_"


class EvaluationDirError(ValueError):
    """The directory holds results of another dataset, metrics configuration, mode or planner configuration."""


def letspi_version() -> str:
    try:
        return version("letspi")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def planner_dir_name(name: str) -> str:
    """A planner label as a directory name (labels may contain ':' and '/')."""
    return "".join(c if c.isalnum() or c in "-_.@+" else "_" for c in name)


def run_record(batch: ScenarioBatch, digests: np.ndarray, scenarios_file: str, config: MetricsConfig,
               mode: EvaluationMode, mode_settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """What ``run.json`` holds: ``identity`` (keyed) and descriptive fields. ``mode_settings``: what else of the
    mode changes answers (closed loop only; absent in open loop, so open-loop keys are unchanged)."""
    identity: dict[str, Any] = {
        "format": RUN_FORMAT,
        "mode": EvaluationMode(mode).value,
        "dataset_digest": dataset_digest(digests),
        "metrics_config": config.recorded(),
    }
    if mode_settings:
        identity["mode_settings"] = mode_settings
    return {
        "identity": identity,
        "key": key_of(identity),
        "dataset": {"file": scenarios_file, "n_scenarios": len(batch)},
        "letspi_version": letspi_version(),
    }


def check_run_file(out_dir: Path, record: dict[str, Any]) -> bool:
    """Refuse a directory keyed differently; True if ``run.json`` is still to be written (it is written
    with the first stored results, so a run that stored nothing leaves no ``run.json``)."""
    run_file = out_dir / "run.json"
    if run_file.exists():
        old = json.loads(run_file.read_text())
        old_identity: dict[str, Any] = old.get("identity") or {"format": old.get("format", 1)}
        if old_identity != record["identity"]:
            changes = diff(old_identity, record["identity"])
            what = "; ".join(changes)
            new_digest = record["identity"]["dataset_digest"]
            if "dataset_digest" in old_identity and old_identity["dataset_digest"] != new_digest:
                was, now = old.get("dataset", {}), record["dataset"]
                what = (f"other scenarios: the directory holds {was.get('n_scenarios')} scenarios from "
                        f"{was.get('file') or '?'}, this run {now['n_scenarios']} from {now['file'] or '?'} "
                        f"(dataset digest {old_identity.get('dataset_digest')} vs "
                        f"{record['identity']['dataset_digest']}); " + what)
            raise EvaluationDirError(f"{out_dir} holds results keyed differently ({what}); "
                                     "use another --out or delete it")
        return False
    return True


def planner_record(built: BuiltPlanner, evaluation: dict[str, Any] | None = None) -> dict[str, Any]:
    """What ``per_scenario/<label>/config.json`` holds. ``evaluation``: how the planner was run when that changes
    its answers (closed loop: mode, replanning period); it joins the identity and key (absent in open loop)."""
    identity = built.config.identity()
    key = built.key
    if evaluation:
        identity = {**identity, "evaluation": evaluation}
        key = key_of(identity)
    record: dict[str, Any] = {"name": built.name, "kind": built.config.kind, "key": key, "identity": identity,
                              "config": built.config.record()}
    if evaluation:
        record["evaluation"] = evaluation
    return record


def check_planner_config(planner_dir: Path, built: BuiltPlanner, evaluation: dict[str, Any] | None = None) -> bool:
    """Refuse another configuration under this planner's name; True if ``config.json`` is still to be
    written (with the planner's first part: a planner that stored nothing leaves no directory)."""
    marker = planner_dir / "config.json"
    record = planner_record(built, evaluation)
    if marker.exists():
        old = json.loads(marker.read_text())
        if old.get("key") != record["key"]:
            changes = diff(old.get("identity") or {}, record["identity"])
            version = record["identity"].get("version")  # a label for the new one: by its version, else its key
            bumped = version is not None and (old.get("identity") or {}).get("version") != version
            label = f"{built.name}-" + (f"v{version}" if bumped else str(record["key"])[:6])
            raise EvaluationDirError(
                f"{planner_dir} holds results of {built.name!r} with another configuration "
                f"(key {old.get('key')} vs {record['key']}: {'; '.join(changes) or 'older letspi format'}); "
                f"use another --out, or give this configuration its own label ({built.relabel(label)})")
        return False
    return True


def remove_empty_dirs(*directories: Path) -> None:
    """Remove ``directories`` (innermost first) that are empty: a failed run leaves no empty shells."""
    for d in directories:
        try:
            d.rmdir()
        except OSError:  # not empty, or already gone
            pass


def _fixed_list(arr: np.ndarray) -> pa.FixedSizeListArray:
    flat = np.ascontiguousarray(arr, dtype=np.float32).reshape(len(arr), -1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def write_part(planner_dir: Path, frame: pd.DataFrame, plan_xy: np.ndarray, plan_vxy: np.ndarray,
               goals: np.ndarray, arrays: dict[str, np.ndarray] | None = None) -> Path:
    """One part file: ``frame``'s rows plus the plan columns and, optionally, more per-row arrays
    (``arrays``: name -> (K, ...), stored flat as float32; names start with ``TRAJECTORY_PREFIX``)."""
    table = pa.Table.from_pandas(frame, preserve_index=False)
    for name, arr in zip(PLAN_COLUMNS, (plan_xy, plan_vxy, goals), strict=True):
        table = table.append_column(name, _fixed_list(arr))
    for name, arr in (arrays or {}).items():
        if not name.startswith(TRAJECTORY_PREFIX):
            raise ValueError(f"extra part column {name!r} must start with {TRAJECTORY_PREFIX!r}")
        table = table.append_column(name, _fixed_list(arr))
    path = planner_dir / f"part-{uuid.uuid4().hex[:16]}.parquet"
    return atomic_write(path, lambda tmp: pq.write_table(table, tmp, compression="zstd"))


def _parts(planner_dir: Path) -> list[Path]:
    return sorted(planner_dir.glob("part-*.parquet"))


class PartWriter:
    """Writes one planner's part files (one writer thread: no locking). Its directory and ``config.json`` appear
    with the first part, after ``before_write()`` (e.g. writing ``run.json``); ``abandon()`` after a failure
    removes a ``config.json`` no part followed and empty directories."""

    def __init__(self, out_dir: Path, built: BuiltPlanner, evaluation: dict[str, Any] | None = None,
                 before_write: Callable[[], None] | None = None) -> None:
        self.planner_dir = out_dir / "per_scenario" / planner_dir_name(built.name)
        if self.planner_dir.is_dir():
            remove_stale_temporaries(self.planner_dir)
        self._record = planner_record(built, evaluation)
        self._config_pending = check_planner_config(self.planner_dir, built, evaluation)
        self._wrote_config = False
        self._before_write = before_write

    def done(self) -> set[str]:
        """Digests of the scenarios already stored."""
        return done_digests(self.planner_dir)

    def todo(self, digests: np.ndarray, progress: ProgressCallback | None = None) -> np.ndarray:
        """Indices of the scenarios ``digests`` (B,) not stored yet; the stored ones are reported to
        ``progress`` as done (a rerun resumes)."""
        done = self.done()
        todo = np.flatnonzero([d not in done for d in digests])
        if progress is not None and len(digests) - len(todo):
            progress(len(digests) - len(todo), None)
        return todo

    def write(self, frame: pd.DataFrame, plan_xy: np.ndarray, plan_vxy: np.ndarray, goals: np.ndarray,
              arrays: dict[str, np.ndarray] | None = None) -> Path:
        if self._before_write is not None:
            self._before_write()
        if self._config_pending:
            atomic_write_text(self.planner_dir / "config.json", json.dumps(self._record, indent=2) + "\n")
            self._config_pending = False
            self._wrote_config = True
        return write_part(self.planner_dir, frame, plan_xy, plan_vxy, goals, arrays)

    def abandon(self) -> None:
        if self._wrote_config and not _parts(self.planner_dir):  # e.g. the first part hit a full disk
            (self.planner_dir / "config.json").unlink(missing_ok=True)
        remove_empty_dirs(self.planner_dir)


def done_digests(planner_dir: Path) -> set[str]:
    done: set[str] = set()
    for part in _parts(planner_dir):
        done.update(pq.read_table(part, columns=["scenario_digest"]).column(0).to_pylist())
    return done


def stored_rows(out_dir: Path, planner_names: Sequence[str]) -> int:
    """Scenario rows stored in ``out_dir`` for ``planner_names`` (what an interrupted run keeps; a
    directory holds one dataset, so no digest needs computing)."""
    return sum(len(done_digests(Path(out_dir) / "per_scenario" / planner_dir_name(n))) for n in planner_names)


def load_planner_results(out_dir: Path, planner_name: str, *, with_plans: bool = False,
                         digests: np.ndarray | None = None) -> pd.DataFrame:
    """All stored rows of one planner (only those of ``digests`` if given), one per digest, in dataset order
    (``row``). ``with_plans`` keeps the plan columns (``plan_xy_m`` etc. as flat float32 arrays per row)."""
    parts = _parts(Path(out_dir) / "per_scenario" / planner_dir_name(planner_name))
    if not parts:
        return pd.DataFrame()
    frames = []
    for p in parts:
        names = pq.read_schema(p).names
        cols = names if with_plans else [c for c in names
                                         if c not in PLAN_COLUMNS and not c.startswith(TRAJECTORY_PREFIX)]
        frames.append(pq.read_table(p, columns=cols).to_pandas())
    frame = pd.concat(frames, ignore_index=True).drop_duplicates("scenario_digest", keep="first")
    if digests is not None:
        frame = frame[frame["scenario_digest"].isin(set(digests))]
    return frame.sort_values("row", kind="stable").reset_index(drop=True)


def load_plans(out_dir: Path, planner_name: str) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Stored plans of one planner: scenario id -> (xy (F, 2), vxy (F, 2), goal (2,)) float64."""
    frame = load_planner_results(out_dir, planner_name, with_plans=True)
    out = {}
    for row in frame.itertuples(index=False):
        xy = np.asarray(row.plan_xy_m, dtype=np.float64).reshape(N_FUTURE, 2)
        vxy = np.asarray(row.plan_vxy_mps, dtype=np.float64).reshape(N_FUTURE, 2)
        out[str(row.scenario_id)] = (xy, vxy, np.asarray(row.plan_goal_xy_m, dtype=np.float64))
    return out


def stored_vehicles(frame: pd.DataFrame) -> tuple[np.ndarray, int]:
    """(n,) ego vehicle of each stored row (its ``GROUP_COLUMN``) and how many rows lacked it (stored by
    an older letspi): those get the recording and ego id of their scenario id (``r01_v5_f100`` ->
    ``r01_v5``), exact within one recording, while recording ids can repeat across generated datasets."""
    ids = frame["scenario_id"].astype(str).str.rsplit("_f", n=1).str[0].to_numpy(dtype=object)
    if GROUP_COLUMN not in frame:
        return ids, len(frame)
    column = frame[GROUP_COLUMN]
    missing = column.isna().to_numpy()
    return np.where(missing, ids, column.astype(str).to_numpy(dtype=object)), int(missing.sum())


def read_summary(out_dir: Path) -> dict[str, Any]:
    """The contents of ``out_dir/metrics.json`` (FileNotFoundError naming it when absent)."""
    path = Path(out_dir) / "metrics.json"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no metrics.json; is {out_dir} an evaluation directory?")
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def reused_windows(out: Path, labels: list[str], batch: ScenarioBatch) -> dict[str, int]:
    """Windows of ``batch`` each planner label already has stored in ``out`` (what a rerun reuses)."""
    if not (out / "per_scenario").is_dir():
        return {}
    digests = {str(d) for d in scenario_digests(batch)}
    return {label: len(digests & done_digests(out / "per_scenario" / planner_dir_name(label))) for label in labels}


def reuse_line(reused: dict[str, int], n_windows: int) -> str | None:
    """``resumed: sf 180 of 200 windows already stored, ...`` (None when nothing was reused)."""
    parts = [f"{label} {n} of {n_windows}" for label, n in reused.items() if n]
    return f"resumed: {', '.join(parts)} windows already stored (not planned again)" if parts else None
