"""A suite's scenarios, cached by the content of their definition (``$LETSPI_BENCHMARK_CACHE``, default
``~/.cache/letspi/benchmark``): ``traffic/<traffic key>/seed_<S>/`` and ``scenarios/<key>/scenarios.arrow``,
``<key>`` adding the extraction to the traffic key. A seed counts once its ``done.json`` is written."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Final

import pandas as pd

from letspi.benchmark.suites import GeneratedTraffic, RealHighD, Suite
from letspi.execution.interrupt import WorkerPool
from letspi.fsutil import atomic_write_text
from letspi.highd.events import read_events
from letspi.highd.io import list_recording_ids, read_recording
from letspi.highd.schema import recording_meta_file, tracks_file, tracks_meta_file
from letspi.highd.types import Recording
from letspi.scenario.extract import critical_windows, enumerate_windows, extract_scenarios
from letspi.scenario.provenance import generation_records
from letspi.scenario.store import save_scenarios
from letspi.trafficgen.generate import generate_highd

#: bump when generated data or extraction change for the same definition (e.g. the writer's number format)
DATA_FORMAT: Final = 1
CACHE_ENV: Final = "LETSPI_BENCHMARK_CACHE"
#: recording ids of seed k (0-based) start at k * RECORDING_ID_STRIDE + 1, so windows of all seeds stay distinct
RECORDING_ID_STRIDE: Final = 100


class SuiteDataError(ValueError):
    """The suite's data cannot be made as defined (too few windows, other HighD files, missing recordings)."""


def cache_root() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "letspi" / "benchmark")


@dataclass(frozen=True)
class SuiteData:
    """A suite's scenarios and their time [s] (0 when cached); ``file_digests``: of the real HighD files read."""

    scenarios_file: Path
    generation_s: float
    extraction_s: float
    reused: bool
    file_digests: dict[int, str] = field(default_factory=dict)


def _digest(payload: object) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.blake2b(text.encode("utf-8"), digest_size=8).hexdigest()


def recording_file_digest(directory: Path, recording_id: int) -> str:
    """SHA-256 (first 16 hex digits) of a recording's three HighD CSV files, in a fixed order."""
    h = hashlib.sha256()
    for name in (recording_meta_file(recording_id), tracks_meta_file(recording_id), tracks_file(recording_id)):
        path = Path(directory) / name
        if not path.is_file():
            raise SuiteDataError(f"{path}: missing (the suite needs recording {recording_id:02d})")
        with path.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def check_highd_files(data: RealHighD, directory: Path, *, allow_other_files: bool,
                      warn: Callable[[str], None]) -> dict[int, str]:
    """The file digests of the suite's recordings in ``directory``; refuses (or warns, with
    ``allow_other_files``) when the suite pins digests and the files differ."""
    if not Path(directory).is_dir():
        raise SuiteDataError(f"{directory}: not a directory (give your HighD data directory with --highd)")
    present = set(list_recording_ids(directory))
    missing = [r for r in data.recording_ids if r not in present]
    if missing:
        raise SuiteDataError(f"{directory}: recording(s) {', '.join(f'{r:02d}' for r in missing)} missing")
    seen = {rid: recording_file_digest(directory, rid) for rid in data.recording_ids}
    differ = [rid for rid, want in data.file_digests.items() if seen.get(rid) != want]
    if differ:
        text = (f"{directory}: recording(s) {', '.join(f'{r:02d}' for r in differ)} differ from the files the "
                "suite was defined on (digests " + ", ".join(f"{seen[r]} vs {data.file_digests[r]}" for r in differ)
                + "): results are not comparable with other users'")
        if not allow_other_files:
            raise SuiteDataError(text + "; --allow-other-files runs anyway")
        warn("warning: " + text)
    return seen


def data_key(suite: Suite, file_digests: dict[int, str] | None = None) -> str:
    payload = {"format": DATA_FORMAT, "data": suite.data.definition(), "extraction": suite.extraction.definition()}
    if file_digests:
        payload["files_seen"] = {str(k): v for k, v in sorted(file_digests.items())}
    return _digest(payload)


def _generate_seed(out: str, seed: int, traffic: GeneratedTraffic) -> float:
    """Generate one seed's recordings into ``out`` (runs in a worker process); its wall time [s]."""
    started = time.perf_counter()
    path = Path(out)
    shutil.rmtree(path, ignore_errors=True)  # a killed earlier try left a partial directory
    report = generate_highd(path, minutes=traffic.minutes, seed=seed, lanes_per_direction=traffic.lanes_per_direction,
                            flow_veh_per_h=traffic.flow_veh_per_h, recording_minutes=traffic.recording_minutes,
                            traffic=traffic.traffic_config())
    elapsed = time.perf_counter() - started
    atomic_write_text(path / "done.json", json.dumps({"seed": seed, "recordings": len(report.paths),
                                                      "events": report.events_written}) + "\n")
    return elapsed


def generate_traffic(traffic: GeneratedTraffic, root: Path, *, workers: int,
                     log: Callable[[str], None]) -> tuple[list[Path], float]:
    """The seed directories (generated where missing, in parallel) and the wall time spent [s]."""
    dirs = [root / f"seed_{s}" for s in traffic.seeds]
    todo = [(d, s) for d, s in zip(dirs, traffic.seeds, strict=True) if not (d / "done.json").exists()]
    if not todo:
        return dirs, 0.0
    started = time.perf_counter()
    log(f"generating {len(todo)} seed(s) x {traffic.minutes:g} min of {traffic.preset} traffic "
        f"({traffic.layout}) in {min(workers, len(todo))} process(es)")
    if workers <= 1 or len(todo) == 1:
        for d, s in todo:
            _generate_seed(str(d), s, traffic)
    else:
        # spawned (a fresh interpreter per worker: one libsumo each); Ctrl-C terminates them at once
        with WorkerPool(min(workers, len(todo))) as pool:
            for future in [pool.submit(_generate_seed, str(d), s, traffic) for d, s in todo]:
                future.result()
    return dirs, time.perf_counter() - started


def _renumbered(rec: Recording, recording_id: int) -> Recording:
    return replace(rec, recording_id=recording_id, meta={**rec.meta, "id": recording_id})


def _load_seed_dirs(
    dirs: list[Path],
) -> tuple[list[Recording], dict[int, pd.DataFrame | None], list[dict[str, object]]]:
    """All seed directories' recordings (ids k * 100 + NN for seed k), their events and generation records."""
    recs: list[Recording] = []
    events: dict[int, pd.DataFrame | None] = {}
    generation: list[dict[str, object]] = []
    for k, d in enumerate(dirs):
        ids = list_recording_ids(d)
        for record in generation_records(d, ids):
            generation.append({**record, "recording": k * RECORDING_ID_STRIDE + int(record["recording"])})
        for rid in ids:
            new_id = k * RECORDING_ID_STRIDE + rid
            recs.append(_renumbered(read_recording(d, rid), new_id))
            events[new_id] = read_events(d, rid)
    return recs, events, generation


def prepare_data(suite: Suite, *, highd_dir: Path | None = None, allow_other_files: bool = False, workers: int = 2,
                 log: Callable[[str], None] = print) -> SuiteData:
    """Make (or reuse) the suite's scenario file."""
    digests: dict[int, str] = {}
    if isinstance(suite.data, RealHighD):
        if highd_dir is None:
            raise SuiteDataError(f"{suite.name} runs on your HighD copy: give its directory with --highd")
        digests = check_highd_files(suite.data, highd_dir, allow_other_files=allow_other_files, warn=log)
    elif highd_dir is not None:
        raise SuiteDataError(f"{suite.name} generates its own traffic; --highd applies to real-data suites only")
    root = cache_root() / "scenarios" / data_key(suite, digests)
    scenarios = root / "scenarios.arrow"
    if scenarios.exists():
        return SuiteData(scenarios, 0.0, 0.0, reused=True, file_digests=digests)
    generation_s = 0.0
    if isinstance(suite.data, GeneratedTraffic):
        traffic_root = cache_root() / "traffic" / _digest({"format": DATA_FORMAT, "data": suite.data.definition()})
        dirs, generation_s = generate_traffic(suite.data, traffic_root, workers=workers, log=log)
        recs, events, generation = _load_seed_dirs(dirs)
        source = str(traffic_root)
    else:
        assert highd_dir is not None
        recs = [read_recording(highd_dir, rid) for rid in suite.data.recording_ids]
        events = {r.recording_id: read_events(highd_dir, r.recording_id) for r in recs}
        generation = generation_records(highd_dir, list(suite.data.recording_ids))
        source = str(highd_dir)
    started = time.perf_counter()
    ex = suite.extraction
    windows = enumerate_windows(recs, ex.stride_frames)
    n_critical = int(critical_windows(recs, windows, events).sum())
    if len(windows) < ex.n_windows or n_critical < round(ex.critical_share * ex.n_windows):
        raise SuiteDataError(f"{suite.name}: the traffic holds {len(windows)} windows ({n_critical} with a conflict); "
                             f"the suite needs {ex.n_windows} ({round(ex.critical_share * ex.n_windows)} with one)")
    batch = extract_scenarios(recs, max_scenarios=ex.n_windows, seed=ex.seed, stride_frames=ex.stride_frames,
                              critical_share=ex.critical_share, events=events)
    provenance = {"source": source, "suite": suite.suite_id, "recordings": [r.recording_id for r in recs],
                  "stride_frames": ex.stride_frames, "max": ex.n_windows, "seed": ex.seed,
                  "windows_available": len(windows), "focus": ex.focus, "critical_share": ex.critical_share,
                  "critical_windows_available": n_critical, "generation": generation}
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / f".scenarios.{os.getpid()}.arrow"
    save_scenarios(batch, tmp, extra_meta={"provenance": provenance})
    os.replace(tmp, scenarios)
    log(f"{suite.name}: {len(batch)} windows of {len(windows)} ({n_critical} with a conflict of the ego)")
    return SuiteData(scenarios, generation_s, time.perf_counter() - started, reused=False, file_digests=digests)
