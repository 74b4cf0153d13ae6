"""Planner options: the user settings a planner kind reads, declared beside the planner as plain data.

The CLI flags, ``letspi planners`` and ``PlannerOptions`` derive from them; an option changes answers only
through the configuration it resolves into, which is what keys results.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from difflib import get_close_matches
from pathlib import Path
from typing import Any, Generic, TypeVar

T = TypeVar("T")

#: the ``--help`` headings planner options are listed under (``PlannerOption.panel``)
PLANNERS_PANEL = "Planners"
DECISION_PANEL = "Decision step"
LLM_PANEL = "LLM"


@dataclass(frozen=True)
class PlannerOption(Generic[T]):
    """One user setting of one or more planner kinds: ``name`` in ``PlannerOptions``, ``type`` as the CLI parses
    it, ``default`` (None: a fallback chosen where it is resolved), one-sentence ``help``, ``unit`` of a number,
    ``flag`` when not ``--name-with-dashes`` (a bool gets ``--no-`` too), allowed ``choices`` of a text option,
    ``panel``: the ``--help`` heading it is listed under (``PLANNERS_PANEL``, ``DECISION_PANEL``, ``LLM_PANEL``)."""

    name: str
    type: Any
    default: T
    help: str
    unit: str = ""
    flag: str = ""
    choices: tuple[str, ...] = ()
    panel: str = PLANNERS_PANEL

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"planner option name {self.name!r} must be a Python identifier")

    @property
    def cli_flag(self) -> str:
        """The flag on the command line (``--sf-params``)."""
        return self.flag or "--" + self.name.replace("_", "-")

    @property
    def keyword(self) -> str:
        """The flag as a Python keyword (``--sf-params`` -> ``sf_params``), which ``letspi.api`` takes too."""
        return self.cli_flag.removeprefix("--").replace("-", "_")

    def describe(self) -> str:
        """The help with its choices and unit."""
        text = self.help
        if self.choices:
            text += f" ({', '.join(self.choices)})"
        return f"{text} [{self.unit}]" if self.unit else text


def file_option(name: str, help: str, *, flag: str = "", panel: str = PLANNERS_PANEL) -> PlannerOption[Path | None]:
    """A file or directory setting: a path, or None for its documented default (shipped file, environment)."""
    return PlannerOption[Path | None](name, Path | None, None, help, flag=flag, panel=panel)


class PlannerOptions:
    """Planner option values by name (others at their defaults), immutable: ``PlannerOptions(top_k=5)``,
    ``options.get(TOP_K)``, ``replace(**values)``; ``check`` rejects misspelt names."""

    _values: dict[str, Any]

    def __init__(self, **values: Any) -> None:
        object.__setattr__(self, "_values", dict(values))

    @classmethod
    def from_keywords(cls, declared: Iterable[PlannerOption[Any]], **keywords: Any) -> PlannerOptions:
        """Options given by the flags' words (``neighbours=``, ``sf_params=``, ``cache=``) or by their names
        (``neighbour_mode=``): ``ValueError`` for a word no option in ``declared`` has (naming the closest)
        or for one option given twice."""
        options = tuple(declared)
        by_word = {o.name: o for o in options} | {o.keyword: o for o in options}
        values: dict[str, Any] = {}
        given: dict[str, str] = {}
        for word, value in keywords.items():
            option = by_word.get(word)
            if option is None:
                close = get_close_matches(word, list(by_word), n=3)
                guess = f"; did you mean {' or '.join(close)}?" if close else ""
                raise ValueError(f"unknown planner option {word}={value!r}{guess} (the planner flags' words, "
                                 "e.g. neighbours= for --neighbours; `letspi planners --json` lists them)")
            if option.name in values:
                raise ValueError(f"{given[option.name]}= and {word}= are one option ({option.cli_flag}); give it once")
            values[option.name], given[option.name] = value, word
        return cls(**values)

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
            close = [m for u in unknown for m in get_close_matches(u, names, n=1)]
            guess = f"; did you mean {' or '.join(close)}?" if close else ""
            raise ValueError(f"unknown planner option(s) {', '.join(unknown)}{guess} (available: "
                             f"{', '.join(sorted(names))})")

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
