"""Dataclasses of arrays that share a leading batch axis (scenarios, windows, memories): ``Batched`` gives
``len(x)``, ``Rows`` also ``x.take(rows)`` (index array, mask or slice) when every field has the batch axis first."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields, replace
from typing import Any, Self

import numpy as np

_FIRST_FIELD: dict[type, str] = {}  # class -> the name of its first field (len is called in loops)


class Batched:
    """Mixin for a dataclass whose first field is an array with the batch axis first."""

    __slots__ = ()

    def __len__(self) -> int:
        cls = type(self)
        if cls not in _FIRST_FIELD:
            _FIRST_FIELD[cls] = fields(cls)[0].name  # type: ignore[arg-type]
        return int(np.shape(getattr(self, _FIRST_FIELD[cls]))[0])


class Rows(Batched):
    """Mixin for a dataclass whose fields are all arrays with the batch axis first."""

    __slots__ = ()

    def take(self, rows: np.ndarray | Sequence[int] | slice) -> Self:
        """The same record for the selected rows of every field."""
        record: Any = self
        return replace(record, **{f.name: getattr(self, f.name)[rows] for f in fields(record)})
