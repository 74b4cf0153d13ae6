"""Shared CLI helpers: progress bars and the one error path of every command.

Every anticipated failure ends in one or two lines on stderr that name the file, field or address
and say what to do, with a non-zero exit code; ``--debug`` (or ``LETSPI_DEBUG=1``) shows the
traceback instead. Exit codes: 2 bad input or setup (file, field, model, server, results key, an
error in a planner of one's own: ``PlannerError`` names it with its file and line), 1 an
unexpected internal error (a bug: please report it with the ``--debug`` output), 130 interrupted
(Ctrl-C; 143 after SIGTERM): one line saying how much is stored (``letspi.execution.interrupt``).
"""

from __future__ import annotations

import errno
import sqlite3
import sys
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

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


def progress_bar() -> Progress:
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


def run_progress(bar: Progress, task: TaskID) -> Callable[[int, RunStatus | None], None]:
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
    """Turn anticipated failures into one or two lines and an exit code (module docstring).

    Yields the command's ``Tally``: a command that resumes (``resumes=True``) calls ``track(total,
    count)`` once it knows its work, so that Ctrl-C prints ``interrupted: N of M stored; rerun the
    same command to resume``; the others keep nothing partial (``interrupted: nothing stored; rerun
    the same command to start again``)."""
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
