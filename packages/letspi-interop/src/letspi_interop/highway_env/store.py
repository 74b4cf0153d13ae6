"""The results directory of highway-env episodes: keyed, resumable, one writer; and its aggregation.

Layout::

    DIR/run.json                           the key: environment, configuration, episode length, replanning
                                           period, highway-env's and gymnasium's versions, metrics configuration
    DIR/episodes/<label>/config.json       the planner's configuration and key, and how it was run
    DIR/episodes/<label>/seed-<S>.npz      every vehicle's states, the road, every plan (compressed)
    DIR/episodes/<label>/seed-<S>.parquet  one row (the seed, ``EPISODE_METRICS``, timing); written last
    DIR/metrics.json, metrics.md           per label the aggregates with 95 % intervals, paired with the reference

One keyed run per directory (another key is refused, naming what differs); atomic writes; a rerun skips the
stored seeds. Intervals: Wilson for rates, a bootstrap over episodes for means (notes/rationale-runtime-evaluation.md).
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from letspi.evaluation.results import letspi_version, planner_dir_name
from letspi.fsutil import atomic_write, atomic_write_text, remove_stale_temporaries
from letspi.keyed import diff, key_of
from letspi.metrics.aggregate import AggValue, finite_mean, format_with_interval, paired_rows, scenario_values
from letspi.metrics.config import MetricsConfig
from letspi.metrics.episode import EPISODE_METRICS, settings_record
from letspi.metrics.registry import MEAN_HOWS, RATE_HOWS
from letspi.metrics.uncertainty import Statistic, StatKind, intervals_of, paired_of, statistics_record
from letspi.planners.outputs import column
from letspi_interop.highway_env.episode import TIMING_KEYS, EpisodeResult
from letspi_interop.highway_env.scene import EpisodeTracks, RoadLayout
from letspi_interop.highway_env.settings import RUN_MODE, EnvSettings, installed_versions

RUN_FORMAT: Final = 1
EPISODES: Final = "episodes"
SEED_COLUMN: Final = "seed"
#: metrics.md's table: (label, key)
TABLE: Final = (("↑ success (%)", "success_pct"), ("↑ survival (s)", "survival_s"),
                ("↓ collision (%)", "collision_pct"), ("↓ at fault (%)", "at_fault_pct"),
                ("↑ speed (m/s)", "mean_speed_mps"), ("↑ distance (m)", "distance_m"),
                ("lane changes", "lane_changes_n"), ("↑ min TTC (s)", "min_ttc_s"),
                ("↓ hard brakes", "hard_brakes_n"), ("↓ peak jerk (m/s³)", "peak_jerk_mps3"),
                ("↓ replan (s)", "planner_latency_s"))
PAIRED: Final = (("success", "success_pct"), ("at fault", "at_fault_pct"), ("collision", "collision_pct"),
                 ("speed (m/s)", "mean_speed_mps"), ("distance (m)", "distance_m"))


class HighwayEnvDirError(ValueError):
    """The directory holds results keyed differently (the message names what differs)."""


def run_record(settings: EnvSettings, config: MetricsConfig) -> dict[str, Any]:
    """``run.json``: the identity of the results (``identity``, ``key``) and descriptive fields."""
    identity = {"format": RUN_FORMAT, "mode": RUN_MODE, "environment": settings.identity(),
                "versions": installed_versions(), "metrics_config": config.recorded(),
                "episode_metrics": settings_record()}
    return {"identity": identity, "key": key_of(identity), "letspi_version": letspi_version()}


def open_run(out: Path, settings: EnvSettings, config: MetricsConfig) -> dict[str, Any]:
    """Check (or write) ``run.json`` of ``out``: a directory keyed differently is refused."""
    out = Path(out)
    record = run_record(settings, config)
    path = out / "run.json"
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("identity") != record["identity"]:
            what = "; ".join(diff(old.get("identity") or {}, record["identity"]))
            raise HighwayEnvDirError(f"{out} holds highway-env results keyed differently ({what}); use another --out "
                                     "or delete it")
        return dict(old)
    atomic_write_text(path, json.dumps(record, indent=2) + "\n")
    return record


def episodes_dir(out: Path, label: str) -> Path:
    return Path(out) / EPISODES / planner_dir_name(label)


class EpisodeWriter:
    """One label's episodes: its ``config.json`` (checked, or written with its first episode) and one pair of
    files per episode. ``done()`` lists the stored seeds."""

    def __init__(self, out: Path, record: Mapping[str, Any]) -> None:
        self.dir = episodes_dir(out, str(record["name"]))
        self.record = dict(record)
        marker = self.dir / "config.json"
        if marker.exists():
            old = json.loads(marker.read_text())
            if old.get("key") != record["key"]:
                what = "; ".join(diff(old.get("identity") or {}, record["identity"]))
                raise HighwayEnvDirError(f"{self.dir} holds results of {record['name']!r} with another configuration "
                                         f"({what}); use another --out or give this one its own label (LABEL=KIND)")
            remove_stale_temporaries(self.dir)
        self._config_pending = not marker.exists()

    def done(self) -> set[int]:
        return {int(p.stem.split("-", 1)[1]) for p in self.dir.glob("seed-*.parquet")} if self.dir.is_dir() else set()

    def write(self, result: EpisodeResult) -> None:
        if self._config_pending:
            atomic_write_text(self.dir / "config.json", json.dumps(self.record, indent=2) + "\n")
            self._config_pending = False
        stem = f"seed-{result.seed}"
        atomic_write(self.dir / f"{stem}.npz", lambda tmp: _write_npz(tmp, result))
        row = {SEED_COLUMN: result.seed, **result.metrics, **{f"time_{k}": v for k, v in result.timing.items()}}
        table = pa.Table.from_pandas(pd.DataFrame([row]), preserve_index=False)
        atomic_write(self.dir / f"{stem}.parquet", lambda tmp: pq.write_table(table, tmp))


def _write_npz(path: Path, result: EpisodeResult) -> None:
    tr = result.tracks
    arrays = {"t_s": tr.t_s, "xy_m": tr.xy_m.astype(np.float32), "vxy_mps": tr.vxy_mps.astype(np.float32),
              "heading_rad": tr.heading_rad.astype(np.float32), "crashed": tr.crashed, "ids": tr.ids,
              "length_m": tr.length_m, "width_m": tr.width_m, "ego": np.array(tr.ego), "ego_on_road": tr.ego_on_road,
              "markings_y_m": result.road.markings_y_m, "speed_limit_mps": np.array(result.road.speed_limit_mps),
              "plan_t_s": result.plan_t_s, "plans_xy_m": result.plans_xy_m,
              **{column(k): v for k, v in result.plan_info.items()}}
    buffer = io.BytesIO()
    savez: Any = np.savez_compressed  # its stubs read the arrays' names as its own keywords
    savez(buffer, **arrays)
    path.write_bytes(buffer.getvalue())


def labels(out: Path) -> list[str]:
    """The labels with results in ``out`` (their ``config.json`` names), sorted."""
    root = Path(out) / EPISODES
    names = [json.loads(p.read_text())["name"] for p in sorted(root.glob("*/config.json"))] if root.is_dir() else []
    return sorted(names)


def load_episodes(out: Path, label: str) -> pd.DataFrame:
    """Every stored episode row of ``label``, sorted by seed (empty without any)."""
    parts = sorted(episodes_dir(out, label).glob("seed-*.parquet"))
    if not parts:
        return pd.DataFrame()
    frame = pd.concat([pq.read_table(p).to_pandas() for p in parts], ignore_index=True)
    return frame.sort_values(SEED_COLUMN, kind="stable").reset_index(drop=True)


def load_episode(out: Path, label: str, seed: int) -> tuple[EpisodeTracks, RoadLayout, np.ndarray, np.ndarray]:
    """One stored episode: its tracks, road, plan times (R,) and plans (R, F, 2)."""
    path = episodes_dir(out, label) / f"seed-{int(seed)}.npz"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no stored episode of {label!r} with seed {seed}")
    with np.load(path) as z:
        tracks = EpisodeTracks(z["t_s"], z["xy_m"].astype(np.float64), z["vxy_mps"].astype(np.float64),
                               z["heading_rad"].astype(np.float64), z["crashed"], z["ids"], z["length_m"], z["width_m"],
                               int(z["ego"]), z["ego_on_road"])
        road = RoadLayout(z["markings_y_m"], float(z["speed_limit_mps"]))
        return tracks, road, z["plan_t_s"], z["plans_xy_m"].astype(np.float64)


# ------------------------------------------------------------------------------------------------
# Aggregation
# ------------------------------------------------------------------------------------------------


def episode_statistics(frame: pd.DataFrame, config: MetricsConfig) -> dict[str, Statistic]:
    """Every rate and mean key of ``EPISODE_METRICS`` with its per-episode values (the key's own definition)."""
    out: dict[str, Statistic] = {}
    for m in EPISODE_METRICS:
        if m.name not in frame:
            continue
        column = frame[m.name].to_numpy()
        for a in m.aggregates:
            if a.how in RATE_HOWS or a.how in MEAN_HOWS:
                kind: StatKind = "rate" if a.how in RATE_HOWS else "mean"
                out[a.key] = Statistic(a.key, kind, scenario_values(a, column, config))
    return out


def aggregate(stats: Mapping[str, Statistic], n: int) -> dict[str, AggValue]:
    """``n`` and every key's value: a rate's share in percent, a mean over the finite values (None: none)."""
    out: dict[str, AggValue] = {"n": n}
    for key, st in stats.items():
        out[key] = float(100.0 * st.values.mean()) if st.kind == "rate" and len(st.values) else (
            finite_mean(st.values)[0] if st.kind == "mean" else None)
    return out


def _timing(frame: pd.DataFrame) -> dict[str, float | None]:
    """Mean wall seconds per episode of each timing part, and letspi's overhead over highway-env's own time."""
    out = {k: float(frame[f"time_{k}"].mean()) for k in TIMING_KEYS if f"time_{k}" in frame}
    he = float(frame["time_highway_env_s"].sum()) if "time_highway_env_s" in frame else 0.0
    ours = sum(float(frame[f"time_{k}"].sum()) for k in ("adapter_s", "plan_s", "control_s", "record_s")
               if f"time_{k}" in frame)
    out["overhead_pct"] = 100.0 * ours / he if he > 0 else float("nan")
    return {k: round(v, 4) if np.isfinite(v) else None for k, v in out.items()}


def summarise(out: Path, seeds: Sequence[int] | None = None, reference: str | None = None,
              config: MetricsConfig | None = None) -> dict[str, Any]:
    """Aggregate every label of ``out`` (on ``seeds`` only, when given) into ``metrics.json`` and ``metrics.md``;
    paired with ``reference`` on the seeds both hold. Returns the metrics.json record."""
    out = Path(out)
    config = config or MetricsConfig(**json.loads((out / "run.json").read_text())["identity"]["metrics_config"])
    frames = {name: load_episodes(out, name) for name in labels(out)}
    if seeds is not None:
        frames = {name: f[f[SEED_COLUMN].isin(list(seeds))].reset_index(drop=True) for name, f in frames.items()}
    frames = {name: f for name, f in frames.items() if len(f)}
    stats = {name: episode_statistics(f, config) for name, f in frames.items()}
    groups = {name: f[SEED_COLUMN].astype(str).to_numpy() for name, f in frames.items()}
    record: dict[str, Any] = {
        "run": json.loads((out / "run.json").read_text()),
        "planners": {name: aggregate(stats[name], len(f)) for name, f in frames.items()},
        "intervals": intervals_of({name: (stats[name], groups[name]) for name in frames}),
        "timing": {name: _timing(f) for name, f in frames.items()},
        "statistics": {**statistics_record(keys=next(iter(stats.values()), None)),
                       "groups": "one group per episode (seed): episodes are independent"},
    }
    if reference is not None and reference in frames:
        record["paired"] = {"reference": reference, "planners": _paired(frames, reference, config)}
    text = json.dumps(record, indent=2, allow_nan=False, default=_json_default)
    atomic_write_text(out / "metrics.json", text + "\n")
    atomic_write_text(out / "metrics.md", summary_markdown(record))
    return record


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _paired(frames: Mapping[str, pd.DataFrame], reference: str, config: MetricsConfig) -> dict[str, Any]:
    subjects = {}
    ref = frames[reference].set_index(SEED_COLUMN)
    for name, frame in frames.items():
        if name == reference:
            continue
        shared = frame[frame[SEED_COLUMN].isin(ref.index)].reset_index(drop=True)
        if not len(shared):
            continue
        other = ref.loc[shared[SEED_COLUMN]].reset_index()
        subjects[name] = (episode_statistics(shared, config), episode_statistics(other, config),
                          shared[SEED_COLUMN].astype(str).to_numpy())
    return paired_of(subjects)


def summary_markdown(record: Mapping[str, Any]) -> str:
    """metrics.md: the table with 95 % intervals, the paired comparisons, the timing."""
    env = record["run"]["identity"]["environment"]
    versions = record["run"]["identity"]["versions"]
    lines = [f"# {env['env_id']}: {json.dumps(env['config'], sort_keys=True)}", "",
             f"{env['duration_s']:g} s episodes, replanning every {env['replan_s']:g} s; highway-env "
             f"{versions.get('highway-env')}, gymnasium {versions.get('gymnasium')}. Values with their 95 % interval "
             "(rates: Wilson; means: bootstrap over episodes).", "",
             "| planner | n | " + " | ".join(label for label, _ in TABLE) + " |", "|---|---:|" + "---:|" * len(TABLE)]
    for name, agg in record["planners"].items():
        own = record["intervals"].get(name, {})
        lines.append(f"| {name} | {agg['n']} | " + " | ".join(format_with_interval(agg.get(key), own.get(key))
                                                             for _, key in TABLE) + " |")
    paired = record.get("paired")
    if paired:
        rows = paired_rows(paired, PAIRED)
        ref = paired["reference"]
        lines += ["", f"Paired with {ref} on the same seeds (Δ = planner − {ref}, 95 % bootstrap interval over "
                      "episodes; rates: episodes where only the planner, only the reference or both have the event, "
                      "exact McNemar p):", "",
                  f"| planner | metric | n | Δ (95 % CI) | only planner | only {ref} | both | p |",
                  "|---|---|---:|---:|---:|---:|---:|---:|", *("| " + " | ".join(r) + " |" for r in rows)]
    lines += ["", "Mean wall seconds per episode (this machine; highway-env's own simulation apart from letspi's "
                  "adapter, planning, tracking and recording; overhead = letspi's share over highway-env's):", "",
              "| planner | highway-env | adapter | planning | tracking | recording | episode | overhead (%) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, t in record["timing"].items():
        cells = [format_with_interval(t.get(k), None, 3) for k in ("highway_env_s", "adapter_s", "plan_s", "control_s",
                                                                  "record_s", "wall_s")]
        overhead = format_with_interval(t.get("overhead_pct"), None, 1)
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {overhead} |")
    return "\n".join(lines) + "\n"
