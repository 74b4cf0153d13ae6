"""Dual-rate LetsPi: the LLM sets the strategy slowly, the physics replans fast (docs/evaluation.md). An answer takes
effect after a fixed latency (reproducible) or its measured one (a background call, the simulation paced to real
time); until then ``default_proposals`` hold. ``release`` (a ``ReleasingPlanner``): at each replan a preset held
since an earlier call gives way to the defaults where the scene observed now no longer calls for it (``checks``:
the gate would not consult or the defaults pass every check; ``prediction``: the defaults pass the prediction's
checks; ``off``: held until the next answer)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Final, Protocol, runtime_checkable

import numpy as np

from letspi.constants import DT_S
from letspi.planners.base import PlanningContext, Proposals, ProposingPlanner
from letspi.scenario.types import ScenarioBatch

DEFAULT_LLM_PERIOD_S: Final = 2.5
#: when a held preset gives way to the defaults (module docstring)
RELEASE_MODES: Final = ("checks", "prediction", "off")
#: ``info`` keys that describe the LLM calls *made* at a replan (0 / NaN at replans without a call)
CALL_INFO_KEYS: Final = ("llm_calls", "llm_cached_calls", "llm_latency_s", "llm_original_latency_s",
                         "prompt_tokens", "completion_tokens")


@dataclass(frozen=True)
class DualRateConfig:
    """How often the LLM is asked: ``llm_period_s`` (t = 0 and every period; >= the horizon: t = 0 only), and when
    its answers take effect: ``llm_latency_s`` (None: measured, not reproducible; else fixed, in the key);
    ``release``: when a held preset gives way to the defaults (``RELEASE_MODES``; in the key unless ``off``)."""

    llm_period_s: float = DEFAULT_LLM_PERIOD_S
    llm_latency_s: float | None = None
    release: str = "checks"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.llm_period_s) and self.llm_period_s > 0):
            raise ValueError(f"--llm-period-s must be a positive number of seconds, got {self.llm_period_s}")
        if self.llm_latency_s is not None and not (math.isfinite(self.llm_latency_s) and self.llm_latency_s >= 0):
            raise ValueError(f"--llm-latency-s must be >= 0 seconds, got {self.llm_latency_s}")
        if self.release not in RELEASE_MODES:
            raise ValueError(f"--release must be one of {', '.join(RELEASE_MODES)}, got {self.release!r}")

    @property
    def measured(self) -> bool:
        return self.llm_latency_s is None

    @property
    def period_frames(self) -> float:
        """LLM period in frames, not rounded (a call at the first replan at or after each multiple of it)."""
        return self.llm_period_s / DT_S

    @property
    def latency_steps(self) -> int:
        """Fixed latency in frames, rounded up (an answer never takes effect early)."""
        return math.ceil((self.llm_latency_s or 0.0) / DT_S - 1e-9)

    def identity(self, releasing: bool = True) -> dict[str, Any]:
        """What joins a planner's key in closed loop: period, fixed latency or ``measured``, and the release mode
        for a planner that holds presets (``releasing``)."""
        latency: float | str = "measured" if self.llm_latency_s is None else round(float(self.llm_latency_s), 6)
        out: dict[str, Any] = {"llm_period_s": round(float(self.llm_period_s), 6), "llm_latency_s": latency}
        if releasing and self.release != "off":  # absent when off: the keys made before release existed
            out["release"] = self.release
        return out


@runtime_checkable
class DualRatePlanner(ProposingPlanner, Protocol):
    """A ``ProposingPlanner`` that says what is in force before its first answer (run so: kind's ``dual_rate``)."""

    def default_proposals(self, batch: ScenarioBatch) -> Proposals: ...


@runtime_checkable
class ReleasingPlanner(Protocol):
    """A dual-rate planner whose held answers the physics can release (module docstring, ``release``)."""

    @property
    def holds_presets(self) -> bool:
        """Whether its answers can be held presets (a decision step); release changes nothing otherwise."""
        ...

    def release_held(self, view: ScenarioBatch, context: PlanningContext, proposals: Proposals,
                     mode: str) -> tuple[Proposals, np.ndarray]:
        """The proposals in force at this replan with every held preset the scene observed now no longer calls
        for (``mode``: ``checks`` or ``prediction``) replaced by the defaults, and (B,) bool which were."""
        ...


@dataclass
class _Call:
    """An LLM call for one scenario: made at ``step`` (frames after t = 0)."""

    row: int
    step: int
    ready_step: int | None = None  # fixed latency: when the answer takes effect
    proposals: Proposals | None = None  # fixed latency: the answer
    future: Future[tuple[Proposals, float]] | None = None  # measured: (answer, wall time of arrival)
    start_s: float = 0.0


@dataclass
class DualRateSchedule:
    """The proposals in force for K scenarios simulated in lockstep. ``step(step, view, context)`` at every physics
    replan (``step``: frames after t = 0) makes the LLM calls due, applies the answers whose latency has passed and
    returns the proposals in force and (K,) info: ``CALL_INFO_KEYS`` of the calls made (measured: arrived) now,
    ``llm_in_force``, ``params_age_s`` [s] (NaN while the fitted parameters hold) and ``llm_answer_latency_s``.
    ``concurrency``: calls in flight at once. Call ``close()`` at the end."""

    planner: DualRatePlanner
    k: int
    config: DualRateConfig = field(default_factory=DualRateConfig)
    concurrency: int = 1
    clock: Callable[[], float] = time.perf_counter
    _in_force: list[Proposals | None] = field(init=False)
    _origin: np.ndarray = field(init=False)  # (K,) step of the call whose answer is in force, NaN = fitted
    _calls: list[_Call] = field(init=False, default_factory=list)
    _pool: ThreadPoolExecutor | None = field(init=False, default=None)
    _next_call: float = field(init=False, default=0.0)  # frames after t = 0 of the next LLM call

    def __post_init__(self) -> None:
        self._in_force = [None] * self.k
        self._origin = np.full(self.k, np.nan)
        if self.concurrency < 1:
            raise ValueError(f"concurrency must be >= 1, got {self.concurrency}")

    def step(self, step: int, view: ScenarioBatch, context: PlanningContext) -> tuple[Proposals, dict[str, np.ndarray]]:
        if len(view) != self.k:
            raise ValueError(f"DualRateSchedule of {self.k} scenarios got a view of {len(view)}")
        info = {key: np.zeros(self.k) for key in CALL_INFO_KEYS}
        info["llm_cached"] = np.full(self.k, np.nan)
        info["llm_answer_latency_s"] = np.full(self.k, np.nan)
        if step >= self._next_call - 1e-9:
            self._ask(step, view, context, info)
            while self._next_call <= step + 1e-9:
                self._next_call += self.config.period_frames
        self._arrivals(step, info)
        defaults: Proposals | None = None
        rows: list[Proposals] = []
        for p in self._in_force:
            if p is None:
                if defaults is None:
                    defaults = self.planner.default_proposals(view.take([0]))
                p = defaults
            rows.append(p)
        info["llm_in_force"] = np.isfinite(self._origin).astype(np.float64)
        info["params_age_s"] = (step - self._origin) * DT_S
        return Proposals.concat(rows), info

    def finish(self, info: dict[str, np.ndarray]) -> None:
        """At the last replan, count the calls answered too late to take effect (finished: their own counts;
        running: one call each). Nothing waits."""
        for call in self._calls:
            if call.future is None:
                continue  # fixed latency: counted when the call was made
            if call.future.done() and call.future.exception() is None:
                _record_call(info, call.row, call.future.result()[0])
            else:
                info["llm_calls"][call.row] += 1.0
        self._calls = []

    def close(self) -> None:
        """Stop waiting for answers still outstanding (they are dropped)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def _propose_one(self, view: ScenarioBatch, context: PlanningContext, row: int) -> Proposals:
        return self.planner.propose(view.take([row]), context.take([row]))

    def _ask(self, step: int, view: ScenarioBatch, context: PlanningContext, info: dict[str, np.ndarray]) -> None:
        rows = range(self.k)
        if self.config.measured:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=self.concurrency, thread_name_prefix="letspi-llm")
            start = self.clock()
            for row in rows:
                fut = self._pool.submit(self._timed, view, context, row)
                self._calls.append(_Call(row, step, future=fut, start_s=start))
            return
        if self.concurrency == 1:
            answers = [self._propose_one(view, context, row) for row in rows]
        else:
            pool = ThreadPoolExecutor(max_workers=self.concurrency, thread_name_prefix="letspi-llm")
            try:
                answers = list(pool.map(lambda r: self._propose_one(view, context, r), rows))
            finally:  # every answer is in when it returns; after Ctrl-C a request in flight is not waited for
                pool.shutdown(wait=False, cancel_futures=True)
        for row, answer in zip(rows, answers, strict=True):
            self._calls.append(_Call(row, step, ready_step=step + self.config.latency_steps, proposals=answer))
            _record_call(info, row, answer)

    def _timed(self, view: ScenarioBatch, context: PlanningContext, row: int) -> tuple[Proposals, float]:
        answer = self._propose_one(view, context, row)
        return answer, self.clock()

    def _arrivals(self, step: int, info: dict[str, np.ndarray]) -> None:
        still: list[_Call] = []
        for call in self._calls:
            if call.future is None:  # fixed latency
                if call.ready_step is not None and call.ready_step <= step:
                    self._apply(call, call.proposals, step, info, (call.ready_step - call.step) * DT_S)
                else:
                    still.append(call)
                continue
            # measured: simulated time since the call may not run ahead of the wall time since it
            due_s = call.start_s + (step - call.step) * DT_S
            remaining = due_s - self.clock()
            if remaining > 0 and not call.future.done():
                try:
                    call.future.result(timeout=remaining)
                except TimeoutError:
                    pass
            if call.future.done():
                answer, arrived_s = call.future.result()  # raises what the call raised
                latency_s = arrived_s - call.start_s
                if latency_s <= (step - call.step) * DT_S + 1e-9:
                    _record_call(info, call.row, answer)
                    self._apply(call, answer, step, info, latency_s)
                    continue
            still.append(call)
        self._calls = still

    def _apply(self, call: _Call, answer: Proposals | None, step: int, info: dict[str, np.ndarray],
               latency_s: float) -> None:
        if answer is None:
            return
        if np.isfinite(self._origin[call.row]) and self._origin[call.row] > call.step:
            return  # a newer answer is already in force
        self._in_force[call.row] = answer
        self._origin[call.row] = call.step
        info["llm_answer_latency_s"][call.row] = latency_s


def _record_call(info: dict[str, np.ndarray], row: int, answer: Proposals) -> None:
    for key in CALL_INFO_KEYS:
        if key in answer.info:
            info[key][row] += float(np.asarray(answer.info[key], dtype=np.float64)[0])
    if "llm_cached" in answer.info:
        info["llm_cached"][row] = float(np.asarray(answer.info["llm_cached"], dtype=np.float64)[0])
