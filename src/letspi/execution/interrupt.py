"""Ctrl-C: how every long command stops (docs/reliability.md). Inside ``handling()`` the first SIGINT or SIGTERM
becomes ``KeyboardInterrupt`` (even when SIGINT started ignored); worker processes never see it; ``finish`` ends
every descendant, prints ``stop_line`` and exits 130 (143 after SIGTERM); a second signal exits at once. Library use
and in-process tests keep Python's own Ctrl-C."""

from __future__ import annotations

import multiprocessing
import multiprocessing.resource_tracker
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess
from pathlib import Path
from types import FrameType
from typing import Any, Final, NoReturn, TypeVar

import numpy  # noqa: F401  (loads NumPy's BLAS before enter_worker limits it)
from threadpoolctl import threadpool_limits

T = TypeVar("T")

STOP_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
#: seconds a child process gets to exit after SIGTERM before it is killed
CHILD_GRACE_S: Final = 1.0
RESUME_HINT: Final = "rerun the same command to resume"
#: ``-W`` option for multiprocessing's resource tracker: after a stop ends the workers it may warn of the
#: semaphores they held (it removes them all the same), a second line after the one stop line
QUIET_TRACKER: Final = "ignore:resource_tracker:UserWarning"


@dataclass
class _State:
    active: bool = False  # inside handling(): this process is the letspi command
    signum: int | None = None  # the first stop signal
    count: int = 0
    reported: bool = False  # the stop line was printed
    cleanups: dict[int, Callable[[], object]] = field(default_factory=dict)


_state = _State()


def received() -> int | None:
    """The first stop signal this process got inside ``handling()`` (None: none)."""
    return _state.signum


def exit_code() -> int:
    """128 + the first stop signal (130 for Ctrl-C, also when no signal came: a ``KeyboardInterrupt``)."""
    return 128 + (_state.signum or signal.SIGINT)


def stop_line(stored: int | None = None, total: int | None = None, *, resumes: bool | None = False) -> str:
    """The one line an interrupted command prints. ``resumes``: True, it resumes with ``stored`` of its
    ``total`` units stored (the count left out when unknown); False, it keeps nothing partial; None, unknown."""
    if resumes is None:
        return "interrupted: rerun the same command"
    if not resumes:
        return "interrupted: nothing stored; rerun the same command to start again"
    if stored is None or total is None:
        return f"interrupted: {RESUME_HINT}"
    return f"interrupted: {stored} of {total} stored; {RESUME_HINT}"


@dataclass
class Tally:
    """What a running command keeps if stopped: ``total`` units and ``count()`` of those stored (read at the stop)."""

    resumes: bool = False
    total: int | None = None
    count: Callable[[], int] | None = None

    def track(self, total: int, count: Callable[[], int]) -> None:
        """The command resumes; ``count()`` says how many of ``total`` units are stored."""
        self.resumes, self.total, self.count = True, int(total), count

    def line(self) -> str:
        """``stop_line`` with the count as it stands (unknown if counting fails)."""
        stored = None
        if self.count is not None:
            try:
                stored = int(self.count())
            except Exception:  # e.g. a part being renamed: say less rather than fail the stop
                stored = None
        return stop_line(stored, self.total, resumes=self.resumes)


def mark_reported() -> None:
    """The stop line was printed (``handling`` prints a generic one otherwise)."""
    _state.reported = True


def on_stop(cleanup: Callable[[], object]) -> Callable[[], None]:
    """Run ``cleanup`` when a stop signal ends the command (e.g. a local Ray's shutdown); returns its unregister."""
    key = id(cleanup)
    _state.cleanups[key] = cleanup

    def unregister() -> None:
        _state.cleanups.pop(key, None)

    return unregister


def start_worker(process: BaseProcess) -> None:
    """Start a worker process that the terminal's Ctrl-C does not reach (SIGINT blocked until ``enter_worker``)."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        process.start()
        return
    # multiprocessing starts its resource tracker with the first child and then *unblocks* SIGINT in
    # the calling thread: start it first, so the mask below holds while the worker starts
    multiprocessing.resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        process.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def enter_worker() -> None:
    """First call in a worker process: ignore Ctrl-C (its parent stops it) and drop one that arrived during start-up;
    SIGTERM raises ``SystemExit`` so the worker's cleanup runs. BLAS runs on one thread here."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # OpenBLAS builds loaded later (SciPy's) read it when they load
    threadpool_limits(1, user_api="blas")  # NumPy's, loaded with this module
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # discards a pending SIGINT
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _exit_on_sigterm(signum: int, frame: FrameType | None) -> None:
    # once: a second SIGTERM (a pool terminates all workers when one exits) must not interrupt the cleanup
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise SystemExit(128 + signum)


def run_worker(body: Callable[[], object]) -> None:
    """A worker process's life: ``enter_worker``, ``body()``; on SIGTERM its ``finally`` blocks run, then ``os._exit``
    (a spawned interpreter's teardown is slow)."""
    enter_worker()
    try:
        body()
    except SystemExit as stop:
        _exit_now(stop)


def _in_worker(fn: Callable[..., T], *args: Any) -> T:
    """A ``WorkerPool`` item: on SIGTERM its ``finally`` blocks run, then the worker ends (not the next item)."""
    try:
        return fn(*args)
    except SystemExit as stop:
        _exit_now(stop)


def _exit_now(stop: SystemExit) -> NoReturn:
    _flush()
    os._exit(stop.code if isinstance(stop.code, int) else 1)


class WorkerPool:
    """Spawned workers that ignore Ctrl-C; leaving the ``with`` block by an exception cancels queued items and
    terminates them, a normal exit waits."""

    def __init__(self, max_workers: int) -> None:
        self._pool = ProcessPoolExecutor(max_workers=max_workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=enter_worker)

    def submit(self, fn: Callable[..., T], *args: Any) -> Future[T]:
        """``fn(*args)`` in a worker (a worker starts here, when the pool needs one)."""
        multiprocessing.resource_tracker.ensure_running()  # see start_worker
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if hasattr(signal, "pthread_sigmask") else None
        try:
            return self._pool.submit(_in_worker, fn, *args)
        finally:
            if old is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        if exc_type is None:
            self._pool.shutdown(wait=True)
            return
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        deadline = time.monotonic() + CHILD_GRACE_S
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()


def _proc_stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, state letter) of a process from /proc (None: gone, or no /proc)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()  # the name, in parentheses, may contain spaces
    return int(fields[1]), fields[0]


def descendants(pid: int | None = None) -> list[int]:
    """Descendants of ``pid`` (default: this process), parents first, from /proc (else multiprocessing's children)."""
    root = os.getpid() if pid is None else pid
    try:
        names = os.listdir("/proc")
    except OSError:
        return [p.pid for p in multiprocessing.active_children() if p.pid is not None] if pid is None else []
    children: dict[int, list[int]] = {}
    for name in names:
        if name.isdigit():
            stat = _proc_stat(int(name))
            if stat is not None:
                children.setdefault(stat[0], []).append(int(name))
    out: list[int] = []
    frontier = [root]
    while frontier:
        kids = [k for p in frontier for k in children.get(p, [])]
        out.extend(kids)
        frontier = kids
    return out


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    stat = _proc_stat(pid)
    if stat is not None:
        return stat[1] not in ("Z", "X")
    if Path("/proc/self").exists():  # Linux, and no entry: gone
        return False
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    return True


def _resource_tracker_pid() -> int | None:
    """multiprocessing's resource tracker: it ignores SIGTERM and exits by itself with this process."""
    tracker = getattr(multiprocessing.resource_tracker, "_resource_tracker", None)
    return getattr(tracker, "_pid", None)


def _ignores_sigterm(pid: int) -> bool:
    """Whether process ``pid`` ignores SIGTERM (its SigIgn mask in /proc; False where unknown)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("SigIgn:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    return False


def _signal_all(pids: list[int], signum: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, signum)
        except OSError:  # gone meanwhile
            pass


def stop_children(grace_s: float = CHILD_GRACE_S) -> None:
    """End what this process started (only inside ``handling()``): the ``on_stop`` cleanups, then SIGTERM to every
    descendant process, SIGKILL to those still running after ``grace_s``."""
    if not _state.active:
        return
    cleanups = list(_state.cleanups.values())
    _state.cleanups.clear()
    for cleanup in cleanups:
        try:
            cleanup()
        except Exception:  # a cleanup that fails must not hide the others (or the stop line)
            pass
    pids = [p for p in descendants() if p != _resource_tracker_pid()]
    _signal_all(pids, signal.SIGTERM)
    _signal_all([p for p in pids if _ignores_sigterm(p)], signal.SIGKILL)  # e.g. Ray's agents: no use waiting
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.02)
    _signal_all([p for p in pids if alive(p)], signal.SIGKILL)
    multiprocessing.active_children()  # reaps the multiprocessing children just ended


def _end_at_once() -> NoReturn:
    """The second stop signal: kill every descendant, exit without any further cleanup."""
    if not _state.reported:
        os.write(2, f"interrupted again: stopped at once; {RESUME_HINT}\n".encode())
    _signal_all(descendants(), signal.SIGKILL)
    os._exit(exit_code())


def _on_signal(signum: int, frame: FrameType | None) -> None:
    _state.count += 1
    if _state.count == 1:
        _state.signum = signum
        raise KeyboardInterrupt
    _end_at_once()


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed, or a broken pipe
            pass


def finish() -> NoReturn:
    """After a stop signal: end the children, print the stop line unless printed, exit at once with ``exit_code()``."""
    stop_children()
    if not _state.reported:
        sys.stderr.write(stop_line(resumes=None) + "\n")
        _state.reported = True
    _flush()
    # not SystemExit: it would wait for worker threads still in an LLM request, and teardown is slow with Ray
    os._exit(exit_code())


@contextmanager
def handling() -> Iterator[None]:
    """Stop signals for the block (main thread, the ``letspi`` command): the first becomes ``KeyboardInterrupt``
    and leaving the block then ``finish``es; the second ends the process at once."""
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    _state.active, _state.signum, _state.count, _state.reported = True, None, 0, False
    if QUIET_TRACKER not in sys.warnoptions:  # passed on to the tracker when it starts (with the first worker)
        sys.warnoptions.append(QUIET_TRACKER)
    for s in STOP_SIGNALS:
        signal.signal(s, _on_signal)  # also over an inherited SIG_IGN (module docstring)
    try:
        try:
            yield
        except (KeyboardInterrupt, SystemExit):
            if _state.signum is None:
                raise
        if _state.signum is not None:
            finish()  # still under these handlers: a second signal ends it at once
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        _state.active = False
