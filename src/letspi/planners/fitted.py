"""Fitted files: values a planner uses and the data they came from, in one JSON file
(``{"<field>": {name: value}, "provenance": {...}, "objective": {...}}``); one per kind ships in ``letspi/data``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from letspi.fsutil import atomic_write_text, provenance_record

T = TypeVar("T")


@dataclass(frozen=True)
class FittedFile:
    """One kind of fitted file: its values' ``field``, the ``shipped`` file in ``letspi.data``, what a reader
    calls it (``what``) and the ``command`` that makes one."""

    field: str
    shipped: str
    what: str
    command: str

    def load(self, path: Path | None, parse: Callable[[Mapping[str, Any]], T]) -> tuple[T, dict[str, Any]]:
        """``parse(values)`` of ``path`` (default: the shipped fit) and the whole record; ``FileNotFoundError``
        or ``ValueError`` naming the file."""
        if path is None:
            text = resources.files("letspi.data").joinpath(self.shipped).read_text()
            where = f"letspi/data/{self.shipped}"
        else:
            try:
                text = Path(path).read_text()
            except FileNotFoundError as exc:
                raise FileNotFoundError(f"{path}: no such {self.what} (create one with `{self.command}`)") from exc
            where = str(path)
        try:
            record = json.loads(text)
            value = parse(record[self.field])
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{where}: not a valid {self.what} ({exc})") from exc
        return value, record

    def save(self, path: Path, values: Mapping[str, Any], provenance: Mapping[str, Any],
             objective: Mapping[str, Any]) -> Path:
        """Write ``values`` with their provenance (``provenance_record``) and objective to ``path`` atomically."""
        record = {self.field: dict(values), "provenance": provenance_record(dict(provenance)),
                  "objective": dict(objective)}
        return atomic_write_text(Path(path), json.dumps(record, indent=2) + "\n")
