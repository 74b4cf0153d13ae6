"""Planner options: the user settings a planner kind reads, declared beside the planner as plain data.

Each planner module declares its kind's options and its planner-table entry lists them; the CLI flags,
``letspi planners`` and ``PlannerOptions`` all derive from those declarations. An option changes answers
only through the configuration it resolves into, which is what keys results.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class PlannerOption(Generic[T]):
    """One user setting of one or more planner kinds: ``name`` in ``PlannerOptions``, ``type`` as the CLI parses
    it, ``default`` (None: a fallback chosen where it is resolved), one-sentence ``help``, ``unit`` of a number,
    ``flag`` when not ``--name-with-dashes`` (a bool gets ``--no-`` too), allowed ``choices`` of a text option."""

    name: str
    type: Any
    default: T
    help: str
    unit: str = ""
    flag: str = ""
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"planner option name {self.name!r} must be a Python identifier")

    @property
    def cli_flag(self) -> str:
        """The flag on the command line (``--sf-params``)."""
        return self.flag or "--" + self.name.replace("_", "-")

    def describe(self) -> str:
        """The help with its choices and unit."""
        text = self.help
        if self.choices:
            text += f" ({', '.join(self.choices)})"
        return f"{text} [{self.unit}]" if self.unit else text


def file_option(name: str, help: str, *, flag: str = "") -> PlannerOption[Path | None]:
    """A file or directory setting: a path, or None for its default (a shipped file, an environment variable)."""
    return PlannerOption[Path | None](name, Path | None, None, help, flag=flag)


class PlannerOptions:
    """Planner option values by name (others at their defaults), immutable: ``PlannerOptions(top_k=5)``,
    ``options.get(TOP_K)``, ``replace(**values)``; ``check`` rejects misspelt names."""

    _values: dict[str, Any]

    def __init__(self, **values: Any) -> None:
        object.__setattr__(self, "_values", dict(values))

    def get(self, option: PlannerOption[T]) -> T:
        value: T = self._values.get(option.name, option.default)
        return value

    def replace(self, **values: Any) -> PlannerOptions:
        return PlannerOptions(**{**self._values, **values})

    def check(self, declared: Iterable[PlannerOption[Any]]) -> None:
        """``ValueError`` naming every given name that no option in ``declared`` has."""
        names = {option.name for option in declared}
        unknown = sorted(set(self._values) - names)
        if unknown:
            raise ValueError(f"unknown planner option(s) {', '.join(unknown)}; available: {', '.join(sorted(names))}")

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("PlannerOptions is immutable; use replace()")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PlannerOptions) and self._values == other._values

    def __hash__(self) -> int:
        return hash(tuple(sorted((k, repr(v)) for k, v in self._values.items())))

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v!r}" for k, v in sorted(self._values.items()))
        return f"PlannerOptions({inner})"


def unique_options(groups: Iterable[Iterable[PlannerOption[Any]]]) -> tuple[PlannerOption[Any], ...]:
    """The options of several kinds, each once, in first-seen order (``ValueError``: two declarations, one name)."""
    seen: dict[str, PlannerOption[Any]] = {}
    for group in groups:
        for option in group:
            other = seen.setdefault(option.name, option)
            if other != option:
                raise ValueError(f"planner option {option.name!r} is declared twice, differently: {other} vs {option}")
    return tuple(seen.values())


#: every option at its default (what library callers start from: ``DEFAULT_OPTIONS.replace(goals="kinematic")``)
DEFAULT_OPTIONS = PlannerOptions()
