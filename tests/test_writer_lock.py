"""One writer per results directory or memory bank, with two real processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from letspi.fsutil import DIRECTORY_LOCK, OutputLockedError, lock_file_of, writer_lock
from letspi.metrics.aggregate import aggregate_metrics
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import concat_batches

HOLD = """
import sys, time
from pathlib import Path
from letspi.fsutil import writer_lock
with writer_lock(Path(sys.argv[1]), "letspi evaluate (test holder)", directory=sys.argv[2] == "dir"):
    print("locked", flush=True)
    time.sleep(600)
"""


def _letspi(*args: str) -> subprocess.CompletedProcess[str]:
    # a wide terminal, so that "one line" is not the terminal's wrapping
    return subprocess.run([sys.executable, "-c", "from letspi.cli.app import main; main()", *args],
                          capture_output=True, text=True, timeout=300, check=False,
                          env={**os.environ, "COLUMNS": "400"})


def _holder(path: Path, kind: str = "dir") -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(path), kind], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
    return proc


@pytest.fixture
def scenarios(tmp_path: Path) -> Path:
    batch = concat_batches([straight_road_scenario(scenario_id=f"s{i}", neighbours=[VehicleSpec(25.0, 27.0)])
                            for i in range(3)])
    return save_scenarios(batch, tmp_path / "s.arrow")


@pytest.fixture
def held(tmp_path: Path) -> Iterator[tuple[Path, subprocess.Popen[str]]]:
    out = tmp_path / "ev"
    proc = _holder(out)
    try:
        yield out, proc
    finally:
        proc.kill()
        proc.wait()


def test_a_second_writer_is_refused_with_one_line_naming_the_holder(
        scenarios: Path, held: tuple[Path, subprocess.Popen[str]], tmp_path: Path) -> None:
    out, holder = held
    done = _letspi("evaluate", "--scenarios", str(scenarios), "--planner", "cv", "--out", str(out))
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and f"process {holder.pid}" in lines[0] and str(out) in lines[0], done.stderr
    assert sorted(p.name for p in out.iterdir()) == [DIRECTORY_LOCK]  # nothing written beside the holder's lock
    generate = _letspi("data", "generate", "--out", str(out), "--minutes", "0.1")
    assert generate.returncode == 2 and f"process {holder.pid}" in generate.stderr


def test_a_memory_bank_has_one_writer(scenarios: Path, tmp_path: Path) -> None:
    bank = tmp_path / "memory.sqlite"
    holder = _holder(bank, "file")
    try:
        done = _letspi("collect", "--scenarios", str(scenarios), "--memory", str(bank), "--llm", "scripted:default",
                       "--no-cache")
        assert done.returncode == 2 and f"process {holder.pid}" in done.stderr, done.stderr
        assert not bank.exists()
    finally:
        holder.kill()
        holder.wait()


def test_the_lock_of_a_killed_writer_is_taken_over(scenarios: Path, tmp_path: Path) -> None:
    out = tmp_path / "ev"
    holder = _holder(out)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert (out / DIRECTORY_LOCK).exists()  # a killed process cannot clean up
    done = _letspi("evaluate", "--scenarios", str(scenarios), "--planner", "cv", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert (out / "metrics.json").exists() and not (out / DIRECTORY_LOCK).exists()


def test_in_process_lock_is_exclusive_and_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "new" / "dir"
    with writer_lock(out, "first"):
        assert lock_file_of(out, directory=True).exists()
        proc = subprocess.run([sys.executable, "-c", HOLD, str(out), "dir"], capture_output=True, text=True,
                              timeout=60, check=False)
        assert proc.returncode != 0 and "OutputLockedError" in proc.stderr and f"process {os.getpid()}" in proc.stderr
        assert "(first)" in proc.stderr
    assert not out.exists()  # created for the lock, nothing written: removed again
    with pytest.raises(OutputLockedError), writer_lock(out), writer_lock(out):
        pass  # a second flock on another open file of the same process is refused too


def test_aggregation_refuses_a_scenario_stored_twice() -> None:
    frame = pd.DataFrame({"scenario_digest": ["a", "b", "a"], "collision": np.zeros(3, dtype=bool)})
    with pytest.raises(ValueError, match="1 scenario.* more than once"):
        aggregate_metrics(frame)


def test_a_lock_that_cannot_be_opened_names_the_output(tmp_path: Path) -> None:
    out = tmp_path / "ev"
    (out / DIRECTORY_LOCK).mkdir(parents=True)  # opening it as a file fails, even for root
    with pytest.raises(IsADirectoryError) as caught, writer_lock(out):
        pass
    assert caught.value.filename == str(out)
