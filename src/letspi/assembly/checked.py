"""Calls into planner kinds from outside letspi, checked, so that their errors blame the right code.

``resolve_config``, ``build_planner_of`` and ``CheckedPlanner.plan`` turn an exception raised in a plug-in's
``resolve``, ``build`` or ``plan`` into a ``PlannerError`` naming the planner, where its kind comes from and the file
and line, and check what they return (types, shapes). Built-in kinds are called as they are."""

from __future__ import annotations

import inspect
import numbers
import os
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from letspi.assembly.build import Builder
from letspi.assembly.planner_table import BUILT_IN, PLUGIN_DOC, PlannerKind, kind_origin
from letspi.assembly.resolve import Resolver
from letspi.constants import N_FUTURE
from letspi.planners.base import PlanBatch, Planner
from letspi.planners.config import PlannerConfig
from letspi.scenario.types import ScenarioBatch

LETSPI_DIR = str(Path(__file__).resolve().parents[1])


class PlannerError(Exception):
    """An error in a planner kind from outside letspi: ``str()`` is one line naming the planner, where its
    kind comes from and where in its code; ``hint`` says what to do."""

    def __init__(self, message: str, hint: str = "") -> None:
        super().__init__(message)
        self.hint = hint


def is_built_in(kind: PlannerKind[Any]) -> bool:
    return any(kind is k for k in BUILT_IN.kinds)


def code_roots(kind: PlannerKind[Any]) -> tuple[str, ...]:
    """The files and directories of a kind's code: the top-level package (or module file) of its
    ``resolve``, ``build`` and configuration class."""
    return tuple(sorted({root for obj in (kind.resolve, kind.build, kind.config_class) for root in module_root(obj)}))


def module_root(obj: Any) -> tuple[str, ...]:
    """The top-level package directory (or module file) ``obj`` is defined in; () for letspi's own."""
    name = (getattr(obj, "__module__", None) or "").partition(".")[0]
    top = sys.modules.get(name)
    if top is None or name == "letspi":
        return ()
    file = getattr(top, "__file__", None)
    if not file:  # a namespace package (a folder without __init__.py)
        return tuple(str(Path(p).resolve()) for p in getattr(top, "__path__", []))
    path = Path(file).resolve()
    return (str(path.parent) if path.name == "__init__.py" else str(path),)


def _shown(path: str) -> str:
    """A file as the user knows it: relative to the working directory when inside it."""
    try:
        return os.path.relpath(path) if Path(path).resolve().is_relative_to(Path.cwd()) else path
    except ValueError:
        return path


def raised_at(exc: BaseException, roots: Sequence[str]) -> str | None:
    """``file:line in function`` of the innermost frame of ``exc``'s traceback in the plug-in's code
    (``roots``), else the innermost frame outside letspi; None when every frame is letspi's."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if any(str(Path(f.filename).resolve()).startswith(r) for r in roots)]
    outside = [f for f in frames if not str(Path(f.filename).resolve()).startswith(LETSPI_DIR)]
    chosen = ours or outside
    if not chosen:
        return None
    frame = chosen[-1]
    return f"{_shown(frame.filename)}:{frame.lineno} in {frame.name}"


def defined_at(obj: Any) -> str:
    """``file:line`` where a function or class is defined ("" when unknown)."""
    try:
        file = inspect.getsourcefile(obj)
        _, line = inspect.getsourcelines(obj)
    except (OSError, TypeError):
        return ""
    return f"{_shown(file)}:{line}" if file else ""


class _Caller:
    """How the errors of one kind's planner are named (``origin`` default: ``kind_origin``)."""

    def __init__(self, kind: PlannerKind[Any], label: str, origin: str | None = None) -> None:
        self.kind, self.label = kind, label
        self.roots = code_roots(kind)
        self.who = f"planner {label!r} ({origin or kind_origin(kind.name)})"

    def raised(self, what: str, exc: Exception) -> Exception:
        """The error to raise for ``exc`` raised while calling the plug-in's ``what``: letspi's own errors
        (files, models, configurations) pass as they are; the rest become a ``PlannerError``."""
        if isinstance(exc, OSError | PlannerError) or type(exc).__module__.startswith("letspi."):
            return exc
        at = raised_at(exc, self.roots)
        where = f" ({at})" if at else ""
        return PlannerError(f"{self.who}: {what} raised {type(exc).__name__}: {exc}{where}",
                            "This is an error in the planner's own code, not in letspi: fix it there "
                            "(--debug shows the traceback).")

    def wrong(self, what: str, fix: str) -> PlannerError:
        return PlannerError(f"{self.who}: {what}", fix)


def resolve_config(kind: PlannerKind[Any], resolver: Resolver, label: str | None = None) -> PlannerConfig:
    """``kind.resolve(resolver)``, checked for a kind from outside letspi (its ``ValueError``s pass as they are)."""
    if is_built_in(kind):
        config: PlannerConfig = kind.resolve(resolver)
        return config
    caller = _Caller(kind, label or kind.name)
    try:
        config = kind.resolve(resolver)
    except ValueError as exc:
        if type(exc).__module__.startswith("letspi."):
            raise
        raise PlannerError(f"{caller.who}: {exc}") from exc
    except Exception as exc:
        raise caller.raised("resolve", exc) from exc
    if not isinstance(config, kind.config_class):
        raise caller.wrong(f"resolve ({defined_at(kind.resolve)}) returned {_a(config)}, not a "
                           f"{kind.config_class.__name__}", f"Return its configuration, e.g. "
                           f"`return {kind.config_class.__name__}(...)`.")
    return config


def build_planner_of(kind: PlannerKind[Any], builder: Builder, config: PlannerConfig, label: str, *,
                     origin: str | None = None) -> tuple[Planner, float]:
    """``kind.build(builder, config, label)``; for an outside kind, checked, its planner a ``CheckedPlanner``."""
    if is_built_in(kind):
        return kind.build(builder, config, label)
    caller = _Caller(kind, label, origin)
    try:
        result = kind.build(builder, config, label)
    except Exception as exc:
        raise caller.raised("build", exc) from exc
    at = defined_at(kind.build)
    if not (isinstance(result, tuple) and len(result) == 2):
        raise caller.wrong(f"build ({at}) returned {_a(result)}, not (planner, load_s)",
                           "Return the planner and the seconds its model took to load, e.g. "
                           "`return MyPlanner(name=label), 0.0`.")
    planner, load_s = result
    caller.roots = (*caller.roots, *module_root(type(planner)))
    check_planner(caller, planner, at)
    if not isinstance(load_s, numbers.Real) or isinstance(load_s, bool) or not load_s >= 0:
        raise caller.wrong(f"build ({at}) returned load_s={load_s!r}, not seconds >= 0",
                           "Return the model loading time in seconds (0.0 without a model) as the second value.")
    return CheckedPlanner(planner, caller), float(load_s)


def check_planner(caller: _Caller, planner: object, at: str) -> None:
    """The planner a build returned: a ``plan(batch)`` method, a ``name`` and a positive ``batch_size``."""
    cls = type(planner).__name__
    plan = getattr(planner, "plan", None)
    if not callable(plan):
        raise caller.wrong(f"build ({at}) returned {_a(planner)}, which has no plan() method",
                           f"A planner has plan(batch: ScenarioBatch) -> PlanBatch, a name and a batch_size "
                           f"({PLUGIN_DOC}).")
    try:
        inspect.signature(plan).bind(None)
    except TypeError:
        unbound = getattr(type(planner), "plan", plan)
        params = inspect.signature(unbound).replace(return_annotation=inspect.Signature.empty)
        raise caller.wrong(f"{cls}.plan{params} ({defined_at(plan)}) cannot be called as plan(batch)",
                           "Define it as `def plan(self, batch: ScenarioBatch) -> PlanBatch`.") from None
    except ValueError:  # no signature to read (a builtin): the call will tell
        pass
    size = getattr(planner, "batch_size", None)
    if not isinstance(size, numbers.Integral) or isinstance(size, bool) or size < 1:
        raise caller.wrong(f"{cls} has batch_size={size!r}, not a positive int",
                           "Give it `batch_size: int = 4096` (scenarios per plan() call).")
    if not isinstance(getattr(planner, "name", None), str):
        raise caller.wrong(f"{cls} has no name", "Give it `name: str` (build passes the label).")


class CheckedPlanner:
    """A planner of a kind from outside letspi: ``plan`` is checked; every other attribute is the planner's own."""

    def __init__(self, planner: Any, caller: _Caller) -> None:
        self._planner = planner
        self._caller = caller

    @property
    def wrapped(self) -> Any:
        """The planner object the kind's build returned."""
        return self._planner

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # not found on the wrapper itself (e.g. while unpickling)
            raise AttributeError(name)
        return getattr(self._planner, name)

    def __repr__(self) -> str:
        return f"{type(self._planner).__name__}(name={getattr(self._planner, 'name', None)!r})"

    def plan(self, batch: ScenarioBatch) -> PlanBatch:
        caller = self._caller
        try:
            plan = self._planner.plan(batch)
        except Exception as exc:
            raise caller.raised("plan()", exc) from exc
        check_plan(caller, plan, len(batch), type(self._planner).__name__)
        return plan


def check_plan(caller: _Caller, plan: object, n: int, cls: str) -> None:
    """What ``plan`` returned for ``n`` scenarios: a ``PlanBatch`` of (n, N_FUTURE, 2) positions and
    velocities, (n, 2) goals and (n,) info arrays."""
    if not isinstance(plan, PlanBatch):
        raise caller.wrong(f"{cls}.plan() returned {_a(plan)}, not a PlanBatch",
                           "Return letspi.plugin.PlanBatch(xy_m=..., vxy_mps=..., goals_xy_m=...).")
    want = (n, N_FUTURE, 2)
    for field in ("xy_m", "vxy_mps"):
        value = np.asarray(getattr(plan, field))
        if value.shape != want or not np.issubdtype(value.dtype, np.number):
            raise caller.wrong(f"{cls}.plan() returned {field} of shape {value.shape} ({value.dtype}) for {n} "
                               f"scenarios; expected {want}",
                               f"Plan {N_FUTURE} steps (N_FUTURE, t = 0.04 ... 5 s) of x and y for every scenario "
                               "of the batch, in the batch's order.")
    if np.shape(plan.goals_xy_m) != (n, 2):
        raise caller.wrong(f"{cls}.plan() returned goals_xy_m of shape {np.shape(plan.goals_xy_m)}; expected "
                           f"({n}, 2)", "Give one goal (x, y) per scenario (NaN where there is none).")
    for key, value in plan.info.items():
        if np.ndim(value) != 1:
            raise caller.wrong(f"{cls}.plan() returned info[{key!r}] of shape {np.shape(value)}; expected ({n},)",
                               "Each info entry is one value per scenario: a (B,) array.")


def _a(value: object) -> str:
    """``a tuple``, ``an int``, ``None``: what a value is, for a message."""
    if value is None:
        return "None"
    name = type(value).__name__
    return f"{'an' if name[:1].lower() in 'aeiou' else 'a'} {name}"
