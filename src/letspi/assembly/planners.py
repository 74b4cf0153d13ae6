"""Planners by kind: options -> configuration (one ``Resolver``) -> planner (one ``Builder``), through the table;
``build_planners(["sf", "fast=letspi-fast"], options)`` does both halves."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Literal

import numpy as np
from pydantic import Field

from letspi.assembly.build import Builder
from letspi.assembly.checked import build_planner_of, resolve_config
from letspi.assembly.planner_table import (
    BUILT_IN,
    FutureUse,
    PlannerKind,
    PlannerTable,
    is_import_path,
    load_kind,
    loaded_from,
    planner_table,
)
from letspi.assembly.resolve import Resolver
from letspi.keyed import Config
from letspi.metrics.registry import Metric
from letspi.planners.base import Planner
from letspi.planners.config import PlannerConfig
from letspi.planners.llm import LLM_CACHE
from letspi.planners.options import DEFAULT_OPTIONS, PlannerOptions


@dataclass(repr=False)
class BuiltPlanner:
    """A planner with the configuration it was built from (its key). name: the label of its results; load_s: model
    loading at build time [s]; table: its kind's table (capabilities; None: the built-in table, picklable). Its
    repr is one short line (the planner's own may hold weight arrays)."""

    name: str
    config: PlannerConfig
    planner: Planner
    load_s: float = 0.0
    table: PlannerTable | None = field(default=None, repr=False)

    @property
    def key(self) -> str:
        return self.config.key()

    @property
    def kind_arg(self) -> str:
        """The ``--planner`` kind that builds it again in a new process (a name, or ``pkg.mod:NAME``)."""
        return loaded_from(self.config.kind) or self.config.kind

    def relabel(self, label: str) -> str:
        """How to give this configuration the label ``label`` (``--planner LABEL=KIND``; an object: its name)."""
        if isinstance(self.config, ObjectConfig):
            return f"name it {label!r}: {self.config.planner_class.rpartition('.')[2]}(..., name={label!r})"
        return f"--planner {label}={self.kind_arg}"

    def __repr__(self) -> str:
        return f"BuiltPlanner(name={self.name!r}, kind={self.config.kind!r}, key={self.key!r}, load_s={self.load_s:g})"

    @property
    def reads_future(self) -> bool:
        """It gets the recorded future (``human``, oracle goals or neighbours); others see history only."""
        return (self.table or BUILT_IN).reads_future(self.config)

    @property
    def outputs(self) -> tuple[Metric, ...]:
        """The per-scenario values its kind declares (``PlannerKind.outputs``)."""
        return (self.table or BUILT_IN).kind_of(self.config).outputs or ()

    def check_outputs(self, info: Mapping[str, object]) -> None:
        """Refuse per-scenario info its kind does not declare."""
        (self.table or BUILT_IN).kind_of(self.config).check_outputs(info)

    @property
    def dual_rate(self) -> bool:
        """The closed loop asks its model at the LLM period and replans its physics in between."""
        return (self.table or BUILT_IN).kind_of(self.config).dual_rate


def parse_planner_arg(arg: str) -> tuple[str, str]:
    """``KIND`` or ``LABEL=KIND`` (a second configuration of one kind in the same results) -> (label, kind)."""
    label, sep, kind = arg.partition("=")
    if not sep:
        return arg.strip(), arg.strip()
    if not label.strip() or not kind.strip():
        raise ValueError(f"--planner takes KIND or LABEL=KIND, got {arg!r}")
    return label.strip(), kind.strip()


def resolve_planner(kind: str, options: PlannerOptions | None = None, *, env: Mapping[str, str] | None = None,
                    table: PlannerTable | None = None) -> PlannerConfig:
    """The configuration of planner ``kind`` under ``options`` (``ValueError`` for an unknown kind or option)."""
    table = table or planner_table()
    options = options or DEFAULT_OPTIONS
    table.check(options)
    return resolve_config(table.kind(kind), Resolver(options, env))


def build_planner(config: PlannerConfig, name: str | None = None, *, builder: Builder | None = None,
                  table: PlannerTable | None = None) -> BuiltPlanner:
    """Build the planner ``config`` describes (its kind's entry in the table), labelled ``name`` (default: its
    kind); ``builder`` shares models between planners."""
    table = table or planner_table()
    label = name or config.kind
    planner, load_s = build_planner_of(table.kind_of(config), builder or Builder(), config, label)
    return BuiltPlanner(label, config, planner, load_s, None if table is BUILT_IN else table)


def planner_kinds(args: Sequence[str], table: PlannerTable | None = None) -> list[tuple[str, str]]:
    """(label, kind) of ``--planner`` arguments: ``KIND``, ``LABEL=KIND``, or a kind by import path
    (``mypkg.mod:NAME``, ``LABEL=mypkg.mod:NAME``; loaded here, and labelled by its name unless given);
    ``ValueError`` for a kind the table does not have."""
    out = []
    for arg in args:
        label, kind = parse_planner_arg(arg)
        if is_import_path(kind):
            name = load_kind(kind).name
            label, kind = (name if label == kind else label), name
        out.append((label, kind))
    table = table or planner_table()  # after the loads above: kinds by import path are in it
    for _, kind in out:  # an unknown name is refused before any data is read
        table.kind(kind)
    return out


def build_planners(args: Sequence[str], options: PlannerOptions, *, builder: Builder | None = None,
                   env: Mapping[str, str] | None = None, table: PlannerTable | None = None) -> list[BuiltPlanner]:
    """Resolve and build planners given as ``KIND`` or ``LABEL=KIND`` (``planner_kinds``); models load once."""
    labels = planner_kinds(args, table)
    table = table or planner_table()
    table.check(options)
    resolver = Resolver(options, env)
    builder = builder or Builder(cache="default" if options.get(LLM_CACHE) else None)
    seen = [label for label, _ in labels]
    dup = sorted({x for x in seen if seen.count(x) > 1})
    if dup:
        raise ValueError(f"planner label(s) {', '.join(dup)} given twice; use LABEL=KIND for variants")
    return [build_planner(resolve_config(table.kind(kind), resolver, label), label, builder=builder, table=table)
            for label, kind in labels]


# planner objects given as they are (letspi.api) ------------------------------------------------------
#: attributes of a planner object that label or batch it but do not change its plans
_NOT_SETTINGS = frozenset({"name", "batch_size", "reads_future", "version"})


class ObjectConfig(Config):
    """The key of a planner object given as it is (``letspi.api.evaluate([MyPlanner()], ...)``): its class, its
    ``version`` attribute if any, and its public attributes (numbers and text as they are, arrays by content
    digest, anything else by its type only)."""

    kind: Literal["object"] = "object"
    planner_class: str
    version: str | None = None
    settings: dict[str, Any] = Field(default_factory=dict)


def _setting(value: Any) -> Any:
    """A planner object's attribute as it enters its key (``ObjectConfig``)."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if isinstance(value, Enum):
        return _setting(value.value)
    if isinstance(value, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()[:16]
        return f"array {value.dtype}{list(value.shape)} sha256:{digest}"
    if isinstance(value, np.generic):
        return _setting(value.item())
    return f"<{type(value).__name__}>"


def object_config(planner: object) -> ObjectConfig:
    """What identifies the results of a planner object (``ObjectConfig``)."""
    cls = type(planner)
    attributes = vars(planner) if hasattr(planner, "__dict__") else {}
    settings = {k: _setting(v) for k, v in sorted(attributes.items())
                if not k.startswith("_") and k not in _NOT_SETTINGS}
    version = getattr(planner, "version", None)
    return ObjectConfig(planner_class=f"{cls.__module__}.{cls.__qualname__}",
                        version=None if version is None else str(version), settings=settings)


def built_from_object(planner: Any, name: str | None = None) -> BuiltPlanner:
    """A planner object (``plan(batch)``, ``name``, ``batch_size``) as the harness runs it, in this process: keyed
    by ``object_config``, checked (``letspi.assembly.checked``), an oracle when its ``reads_future`` says so."""
    label = name or getattr(planner, "name", None) or type(planner).__name__
    reads = bool(getattr(planner, "reads_future", False))

    def refuse(r: Resolver) -> ObjectConfig:
        raise ValueError("a planner object is given as it is; it has no options to resolve")

    def build(b: Builder, c: ObjectConfig, label: str) -> tuple[Planner, float]:
        return planner, 0.0

    declared = getattr(planner, "outputs", None)  # an object may declare its outputs; else they go unchecked
    kind = PlannerKind[ObjectConfig]("object", "a planner object given as it is", ObjectConfig, refuse, build,
                                     future=FutureUse.ALWAYS if reads else FutureUse.NEVER,
                                     outputs=None if declared is None else tuple(declared))
    config = object_config(planner)
    checked, load_s = build_planner_of(kind, Builder(cache=None), config, label,
                                       origin=f"a {type(planner).__name__} object")
    return BuiltPlanner(label, config, checked, load_s, BUILT_IN.with_kinds(kind))
