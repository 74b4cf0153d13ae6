"""Shared CLI helpers: progress bars and the one error path of every command (``user_errors``): one or two lines
naming the file, field or address (``--debug``: the traceback); exit 2 bad input or setup (an error in a planner
of one's own: ``PlannerError`` names it with its file and line), 1 a bug, 130 interrupted (143 after SIGTERM)."""

from __future__ import annotations

import errno
import os
import sqlite3
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TaskID,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from letspi.assembly.checked import PlannerError
from letspi.cli.startup import DEBUG_ENV, debug_enabled
from letspi.execution import interrupt
from letspi.execution.ordered import RunStats, RunStatus
from letspi.fsutil import OutputLockedError, provenance_command
from letspi.highd.errors import HighDFormatError
from letspi.llm.types import BackendUnavailableError, LLMConfigError, LLMError, ModelNotFoundError
from letspi.simulation.config import EvaluationMode

console = Console(stderr=True)


def command_line() -> str:
    """The command as typed, as manifests and writer locks record it: absolute paths relative to the
    working directory, or by their file name when outside it (``fsutil.provenance_command``)."""
    return provenance_command("letspi", sys.argv[1:])


CONCURRENCY_HELP = ("Scenarios in flight at once for LLM planners and memory collection (default: 1 for llamacpp:, 8 "
                    "for ollama:/openai:; match the server's parallel slots). Never changes results, only their speed.")
ConcurrencyOpt = Annotated[int | None, typer.Option(help=CONCURRENCY_HELP)]


def evaluation_mode(text: str | EvaluationMode) -> EvaluationMode:
    """``--mode``: an ``EvaluationMode`` by its value (a mistyped one names the closest)."""
    try:
        return EvaluationMode(text)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None


def _duration(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class RunColumn(ProgressColumn):
    """Scenarios/s, requests in flight, fallbacks, failures and ETA of a concurrent run (the task's
    ``run`` field, set by ``run_progress``); rich's own time estimate for other tasks."""

    def __init__(self) -> None:
        super().__init__()
        self._remaining = TimeRemainingColumn()

    def render(self, task: Task) -> Text:
        status = task.fields.get("run")
        if not isinstance(status, RunStatus):
            return self._remaining.render(task)
        in_flight = status.requests_in_flight if status.requests_in_flight is not None else status.running
        eta = status.eta_s
        return Text(f"{status.scenarios_per_s:.2f} scenarios/s, {in_flight} in flight, {status.fallbacks} fallbacks, "
                    f"{status.failed} failed, ETA {_duration(eta) if eta is not None else '-:--:--'}",
                    style="progress.remaining")


#: seconds between two lines of a task's progress when stderr is not a terminal
PROGRESS_INTERVAL_ENV = "LETSPI_PROGRESS_INTERVAL_S"


class LineProgress:
    """Progress for logs (stderr not a terminal): one plain line per task at most every ``interval_s``, and
    one when it completes; the same calls as rich's ``Progress`` that the commands make."""

    def __init__(self, out: Console, interval_s: float = 10.0) -> None:
        self.console = out
        self.interval_s = interval_s
        self._tasks: list[dict[str, Any]] = []

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        for i, task in enumerate(self._tasks):
            if not task["reported_done"] and task["completed"] > task["printed"]:
                self._print(TaskID(i))

    def add_task(self, description: str, total: float | None = None, completed: float = 0, **fields: Any) -> TaskID:
        now = time.monotonic()
        self._tasks.append({"description": description, "total": total, "completed": completed, "start": now,
                            "start_completed": completed, "last": now, "printed": -1.0, "reported_done": False,
                            "fields": fields})
        return TaskID(len(self._tasks) - 1)

    def advance(self, task: TaskID, advance: float = 1) -> None:
        self.update(task, advance=advance)

    def update(self, task: TaskID, *, total: float | None = None, completed: float | None = None,
               advance: float | None = None, description: str | None = None, **fields: Any) -> None:
        t = self._tasks[task]
        if total is not None:
            t["total"] = total
        if completed is not None:
            t["completed"] = completed
        if advance is not None:
            t["completed"] += advance
        if description is not None:
            t["description"] = description
        t["fields"].update(fields)
        done = t["total"] is not None and t["completed"] >= t["total"]
        if (done and not t["reported_done"]) or time.monotonic() - t["last"] >= self.interval_s:
            self._print(task)

    def _print(self, task: TaskID) -> None:
        t = self._tasks[task]
        now = time.monotonic()
        t["last"], t["printed"] = now, t["completed"]
        done, total = t["completed"], t["total"]
        rate = (done - t["start_completed"]) / max(now - t["start"], 1e-9)
        parts = [f"{t['description']}: {done:g}" + (f"/{total:g} ({100 * done / total:.0f} %)" if total else "")]
        status = t["fields"].get("run")
        if isinstance(status, RunStatus):
            eta = status.eta_s
            parts.append(f"{status.scenarios_per_s:.2f} scenarios/s, {status.fallbacks} fallbacks, {status.failed} "
                         f"failed, ETA {_duration(eta) if eta is not None else '-:--:--'}")
        else:
            parts.append(f"{rate:.3g}/s, {_duration(now - t['start'])} elapsed")
            if total and rate > 0 and done < total:
                parts.append(f"ETA {_duration((total - done) / rate)}")
        if total is not None and done >= total:
            t["reported_done"] = True
        self.console.print(escape(", ".join(parts)), highlight=False, soft_wrap=True)


def progress_bar() -> Progress | LineProgress:
    """A live progress bar on a terminal; plain lines at a modest rate otherwise (logs, CI)."""
    if not console.is_terminal:
        return LineProgress(console, float(os.environ.get(PROGRESS_INTERVAL_ENV, "10")))
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TaskProgressColumn(),
        TimeElapsedColumn(),
        RunColumn(),
        console=console,
        transient=False,
    )


def run_progress(bar: Progress | LineProgress, task: TaskID) -> Callable[[int, RunStatus | None], None]:
    """Advance ``task`` by k scenarios and show the runner's status (``RunColumn``)."""

    def update(k: int, status: RunStatus | None = None) -> None:
        if status is None:
            bar.advance(task, k)
        else:
            bar.update(task, advance=k, run=status)

    return update


def print_run(name: str, stats: RunStats) -> None:
    """The run summary line: throughput, p50/p95 latency, tokens/s, fallbacks, failures."""
    console.print(f"{escape(name)}: {escape(stats.summary_line())}", highlight=False)


def _fail(message: str, hint: str | None, code: int) -> typer.Exit:
    console.print(f"[red]error:[/red] {escape(message)}", highlight=False)
    if hint:
        console.print(escape(hint), highlight=False)
    return typer.Exit(code=code)


@contextmanager
def user_errors(*, resumes: bool = False) -> Iterator[interrupt.Tally]:
    """Turn anticipated failures into one or two lines and an exit code. Yields the command's ``Tally``: a
    command that resumes (``resumes=True``) calls ``track(total, count)`` once it knows its work, so that
    Ctrl-C prints how much is stored."""
    tally = interrupt.Tally(resumes=resumes)
    try:
        yield tally
    except typer.Exit:
        raise
    except Exception as exc:
        if debug_enabled():
            raise
        raise _classify(exc) from exc
    except KeyboardInterrupt as exc:
        if debug_enabled():  # where it stopped, then the same line and exit code
            traceback.print_exc()
        interrupt.stop_children()  # first: their last messages (e.g. Ray's) come before the line
        console.print(escape(tally.line()), highlight=False, soft_wrap=True)
        interrupt.mark_reported()
        raise typer.Exit(code=interrupt.exit_code()) from exc


#: errors of a path that cannot be created or written (PermissionError is EACCES/EPERM)
_PATH_ERRNOS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR, errno.EEXIST})


def _classify(exc: Exception) -> typer.Exit:
    if isinstance(exc, OutputLockedError):  # one line naming the holder; nothing to add
        return _fail(str(exc), None, 2)
    if isinstance(exc, PlannerError):  # the planner's own code: named, with its file and line
        return _fail(str(exc), exc.hint or None, 2)
    if isinstance(exc, BackendUnavailableError):
        return _fail(str(exc), "The run stopped instead of falling back on every scenario; start the server "
                     "(or fix the address) and rerun the same command to resume.", 2)
    if isinstance(exc, ModelNotFoundError):
        return _fail(str(exc), "`letspi llm models` lists the embedded models; `letspi llm check SPEC` tests a model "
                     "spec before a run.", 2)
    if isinstance(exc, LLMConfigError | LLMError):
        return _fail(str(exc), None, 2)
    if isinstance(exc, HighDFormatError):
        text = str(exc)  # starts with the file name; the directory tells which recording set
        in_dir = exc.path.parent != Path(".") and text.startswith(exc.path.name)
        return _fail(f"{exc.path.parent}/{text}" if in_dir else text,
                     "Fix or re-export this recording, or leave it out (--recordings).", 2)
    if isinstance(exc, FileNotFoundError):
        return _fail(f"{exc.filename}: no such file or directory" if exc.filename else str(exc), None, 2)
    if isinstance(exc, OSError) and (exc.errno == errno.ENOSPC or "No space left" in str(exc)):
        return _fail(f"{exc.filename or 'output'}: no space left on the device",
                     "Free disk space and rerun the same command: finished work is kept.", 2)
    if isinstance(exc, OSError) and exc.errno in _PATH_ERRNOS:
        reason = (exc.strerror or type(exc).__name__).lower()
        return _fail(f"{exc.filename or 'output'}: {reason}",
                     "Choose a location you can write to (e.g. another --out) or fix its permissions.", 2)
    if isinstance(exc, sqlite3.DatabaseError):
        return _fail(f"database error: {exc}", "Is the --memory file a letspi memory bank (SQLite)?", 2)
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        return _fail(f"{exc.filename}: {exc.strerror.lower()}", None, 2)
    if isinstance(exc, KeyError):  # str() of a KeyError is its quoted key
        return _fail(str(exc.args[0]) if exc.args else "missing key", None, 2)
    if isinstance(exc, ValueError | OSError):
        return _fail(str(exc), None, 2)
    return _fail(f"internal error: {type(exc).__name__}: {exc}",
                 f"This is a bug; rerun with --debug (or {DEBUG_ENV}=1) for the traceback and report it.", 1)
