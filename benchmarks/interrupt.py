"""``python -m benchmarks.speed interrupt``: how fast each long command stops on Ctrl-C, what it keeps, and whether
the rerun completes it without duplicates (``letspi.execution.interrupt``).

Each mode runs the real ``letspi`` command in a child process of its own session (as a shell runs a
foreground job), sends SIGINT to its process group (as a terminal's Ctrl-C does: worker processes get it too)
``after_s`` seconds after the start, once it has stored a first unit of work, and measures the seconds from the
signal to the exit. Reported per mode: those seconds, the exit code, the stop line and its counts, the child
processes seen while it ran and those still running after the exit (must be none), and, for the
commands that resume, the rerun: exit code, rows stored and whether any scenario is stored twice.

Modes (the issue's list): ``open-loop`` (``sf-opt``), ``closed-loop`` (``sf`` and ``frenet`` in
``closed-loop-log``, in this process), ``closed-loop-workers`` (the same on 2 worker processes),
``closed-loop-ray`` (on 2 Ray actors; skipped without the ``ray`` extra), ``collect`` (memory
collection with 4 requests in flight against the local test server, each answered after
``llm_latency_s``: a slow model server; against a real llama.cpp server see
``tests/test_interrupt.py``), ``train-llm-data``, ``data-generate`` and ``bench-physics``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from benchmarks.llm_concurrency import _child_env
from benchmarks.llm_server import LlmTestServer
from letspi.evaluation.results import load_planner_results, planner_dir_name
from letspi.execution.interrupt import alive, descendants
from letspi.method.memory import MemoryBank
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import ScenarioBatch

STOP_LINE = re.compile(r"^interrupted: (\d+) of (\d+) stored; rerun the same command to resume$")
MODES = ("open-loop", "closed-loop", "closed-loop-workers", "closed-loop-ray", "collect", "train-llm-data",
         "data-generate", "bench-physics")


@dataclass(frozen=True)
class Stopped:
    """A command stopped by a signal. ``seconds``: from the (last) signal to the exit; ``children``:
    every descendant process seen while it ran; ``left``: those still running after the exit."""

    returncode: int
    stderr: str
    seconds: float
    children: tuple[int, ...]
    left: tuple[int, ...]

    @property
    def stop_lines(self) -> list[str]:
        return [line.strip() for line in self.stderr.splitlines() if "interrupted" in line]

    @property
    def counts(self) -> tuple[int, int] | None:
        """(N, M) of ``interrupted: N of M stored; ...`` when that is the one stop line."""
        lines = self.stop_lines
        match = STOP_LINE.match(lines[0]) if len(lines) == 1 else None
        return (int(match.group(1)), int(match.group(2))) if match else None


class EndedBeforeSignal(RuntimeError):
    """The command finished before it could be interrupted (give it more work or signal it sooner)."""


def letspi_command(*args: str) -> list[str]:
    """The ``letspi`` command line run by this interpreter (and this checkout of letspi)."""
    return [sys.executable, "-m", "letspi.cli.app", *args]


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_and_stop(command: Sequence[str], ready: Callable[[], bool], log: Path, *, signals: int = 1,
                 group: bool = True, ignore_sigint: bool = False, signum: int = signal.SIGINT,
                 timeout_s: float = 600.0, exit_timeout_s: float = 120.0, stdout: Path | None = None) -> Stopped:
    """Start ``command`` in a session of its own, wait for ``ready()``, send ``signum`` ``signals``
    times 0.5 s apart (to the process group, as a terminal's Ctrl-C, or with ``group=False`` to the
    process alone, as ``kill``) and wait for the exit. ``ignore_sigint``: start it with SIGINT
    ignored, as a shell starts ``cmd &`` in a script. Its stderr goes to ``log``. A command still running
    ``exit_timeout_s`` after the signal is killed (``subprocess.TimeoutExpired``)."""
    with open(log, "w") as err, open(stdout or os.devnull, "w") as out:
        proc = subprocess.Popen(list(command), env=_child_env(), stdout=out, stderr=err, start_new_session=True,
                                preexec_fn=_ignore_sigint if ignore_sigint else None)
        children: set[int] = set()
        deadline = time.monotonic() + timeout_s
        sent = time.monotonic()
        try:
            while not ready():
                if proc.poll() is not None:
                    raise EndedBeforeSignal(f"{' '.join(command)} ended before the signal:\n{log.read_text()[-3000:]}")
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{' '.join(command)}: not ready within {timeout_s:.0f} s")
                children.update(descendants(proc.pid))
                time.sleep(0.02)
            children.update(descendants(proc.pid))
            for k in range(signals):
                if k:
                    time.sleep(0.5)
                sent = time.monotonic()
                if group:
                    os.killpg(proc.pid, signum)
                else:
                    proc.send_signal(signum)
            proc.wait(timeout=exit_timeout_s)
            seconds = time.monotonic() - sent
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    time.sleep(0.3)  # a process that outlived its parent shows up as still running
    return Stopped(proc.returncode, log.read_text(), seconds, tuple(sorted(children)),
                   tuple(c for c in sorted(children) if alive(c)))


def _run(command: Sequence[str]) -> tuple[int, float, str]:
    t0 = time.perf_counter()
    done = subprocess.run(list(command), env=_child_env(), capture_output=True, text=True)
    return done.returncode, time.perf_counter() - t0, done.stderr[-2000:]


# ------------------------------------------------------------------------------------------------
# What each mode keeps
# ------------------------------------------------------------------------------------------------


def _evaluation_rows(out: Path, labels: Sequence[str]) -> dict[str, Any]:
    """Rows stored per planner, and whether any scenario is stored twice (across part files)."""
    rows, duplicates = 0, 0
    for label in labels:
        parts = sorted((out / "per_scenario" / planner_dir_name(label)).glob("part-*.parquet"))
        if parts:
            digests = pd.concat([pd.read_parquet(p, columns=["scenario_digest"]) for p in parts])["scenario_digest"]
            duplicates += int(digests.duplicated().sum())
        rows += len(load_planner_results(out, label))
    return {"rows": rows, "duplicates": duplicates}


def _bank_rows(bank: Path) -> dict[str, Any]:
    if not bank.exists():
        return {"rows": 0, "duplicates": 0}
    with MemoryBank.open(bank, readonly=True) as b:  # (scenario, configuration) is unique in the bank
        return {"rows": b.count(validated_only=False), "duplicates": 0}


def _label_rows(out: Path) -> dict[str, Any]:
    """Labelled scenarios (one ``propose`` row each) in the parts written so far."""
    from letspi_train.finetune.labels import PARTS_DIR  # the companion the timed command needs anyway

    parts = sorted((out / PARTS_DIR).glob("part-*.parquet"))
    if not parts:
        return {"rows": 0, "duplicates": 0}
    labels = pd.concat([pd.read_parquet(p, columns=["scenario_index", "kind"]) for p in parts])
    index = labels.loc[labels["kind"] == "propose", "scenario_index"]
    return {"rows": int(index.nunique()), "duplicates": int(index.duplicated().sum())}


@dataclass(frozen=True)
class _Mode:
    command: list[str]
    total: int | None  # units a complete run stores (None: it keeps nothing partial)
    stored: Callable[[], dict[str, Any]] | None = None

    def begun(self) -> bool:
        """The command stores its work: it has loaded its input and is in its loop (a signal before that
        tests start-up, whose length depends on the machine, not the stop). Always true for a mode that
        keeps nothing partial."""
        if self.stored is None:
            return True
        try:
            return self.stored()["rows"] > 0
        except Exception:  # a file being created or renamed: look again
            return False


def _modes(names: Sequence[str], scenario_file: Path, n: int, n_llm: int, n_labels: int, work: Path,
           server: LlmTestServer) -> dict[str, _Mode]:
    data = ["--scenarios", str(scenario_file)]
    both = ["--planner", "sf", "--planner", "frenet", "--mode", "closed-loop-log", "--limit", str(n)]

    def out(name: str) -> Path:
        return work / name

    table: dict[str, Callable[[], _Mode]] = {
        "open-loop": lambda: _Mode(
            letspi_command("evaluate", *data, "--limit", str(n), "--planner", "sf-opt", "--out", str(out("open-loop"))),
            n, lambda: _evaluation_rows(out("open-loop"), ["sf-opt"])),
        "closed-loop": lambda: _Mode(
            letspi_command("evaluate", *data, *both, "--out", str(out("closed-loop"))),
            2 * n, lambda: _evaluation_rows(out("closed-loop"), ["sf", "frenet"])),
        "closed-loop-workers": lambda: _Mode(
            letspi_command("evaluate", *data, *both, "--workers", "2", "--out", str(out("closed-loop-workers"))),
            2 * n, lambda: _evaluation_rows(out("closed-loop-workers"), ["sf", "frenet"])),
        "closed-loop-ray": lambda: _Mode(
            letspi_command("evaluate", *data, *both, "--ray", "--workers", "2", "--out", str(out("closed-loop-ray"))),
            2 * n, lambda: _evaluation_rows(out("closed-loop-ray"), ["sf", "frenet"])),
        "collect": lambda: _Mode(
            letspi_command("collect", *data, "--limit", str(n_llm), "--memory", str(out("bank.sqlite")),
                           "--llm", server.spec(), "--goals", "kinematic", "--no-cache", "--concurrency", "4"),
            n_llm, lambda: _bank_rows(out("bank.sqlite"))),
        "train-llm-data": lambda: _Mode(
            letspi_command("train", "llm-data", *data, "--max", str(n_labels), "--out", str(out("train-llm-data"))),
            n_labels, lambda: _label_rows(out("train-llm-data"))),
        "data-generate": lambda: _Mode(
            letspi_command("data", "generate", "--out", str(out("data-generate")), "--minutes", "10"), None),
        "bench-physics": lambda: _Mode(letspi_command("bench", "physics"), None),
    }
    unknown = sorted(set(names) - set(table))
    if unknown:
        raise ValueError(f"unknown mode(s) {', '.join(unknown)}; available: {', '.join(MODES)}")
    return {name: table[name]() for name in names}


def _after(seconds: float, begun: Callable[[], bool]) -> Callable[[], bool]:
    """Ready ``seconds`` after now once ``begun()`` (asked at most every 0.25 s: it reads the disk)."""
    start = time.monotonic()
    asked = [0.0]

    def ready() -> bool:
        now = time.monotonic()
        if now - start < seconds or now - asked[0] < 0.25:
            return False
        asked[0] = now
        return begun()

    return ready


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def bench_interrupt(batch: ScenarioBatch, *, n: int = 3000, n_llm: int = 40, n_labels: int = 600,
                    modes: Sequence[str] = MODES, after_s: float = 10.0, resume: bool = True,
                    llm_latency_s: float = 2.0, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Each of ``modes`` on the first ``n`` scenarios of ``batch`` (``n_llm`` for ``collect``,
    ``n_labels`` for ``train-llm-data``), SIGINT ``after_s`` s after its start and once it has stored
    something (module docstring);
    ``resume``: rerun the resumable ones to completion and count what they stored. A command that
    ends before the signal is reported as such."""
    say = log or (lambda _m: None)
    if "closed-loop-ray" in modes and importlib.util.find_spec("ray") is None:
        say("closed-loop-ray: skipped (ray is not installed: pip install 'letspi[ray]')")
        modes = [m for m in modes if m != "closed-loop-ray"]
    result: dict[str, Any] = {"scenarios": n, "llm_scenarios": n_llm, "label_scenarios": n_labels, "after_s": after_s,
                              "llm_latency_s": llm_latency_s, "loadavg_start": _load(), "modes": {}}
    with tempfile.TemporaryDirectory(prefix="letspi-bench-interrupt-") as tmp, \
            LlmTestServer(latency_s=llm_latency_s) as server:
        work = Path(tmp)
        most = max(n, n_llm, n_labels)
        if len(batch) < most:
            raise ValueError(f"{len(batch)} scenarios, {most} requested")
        scenario_file = save_scenarios(batch.take(slice(0, most)), work / "scenarios.arrow")
        for name, mode in _modes(modes, scenario_file, n, n_llm, n_labels, work, server).items():
            say(f"{name}: letspi {' '.join(mode.command[3:])}")
            try:
                stopped = run_and_stop(mode.command, _after(after_s, mode.begun), work / f"{name}.err")
            except EndedBeforeSignal:
                say(f"  ended before the signal ({after_s:g} s): give it more work")
                result["modes"][name] = {"ended_before_signal": True}
                continue
            entry: dict[str, Any] = {
                "seconds_to_exit": round(stopped.seconds, 2), "exit_code": stopped.returncode,
                "stop_line": " | ".join(stopped.stop_lines), "one_stop_line": len(stopped.stop_lines) == 1,
                "traceback": "Traceback" in stopped.stderr, "child_processes": len(stopped.children),
                "left_running": len(stopped.left), "loadavg": _load(),
            }
            if mode.stored is not None:
                entry["stored_on_disk"] = mode.stored()["rows"]
                if resume:
                    code, seconds, err = _run(mode.command)
                    entry["rerun"] = {"exit_code": code, "seconds": round(seconds, 1), **mode.stored(),
                                      "expected_rows": mode.total, **({"stderr": err} if code else {})}
            say(f"  {entry}")
            result["modes"][name] = entry
    result["loadavg_end"] = _load()
    return result
