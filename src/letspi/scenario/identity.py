"""Content identity of scenarios and datasets: a scenario id names a window, not its content.

``scenario_digests``: BLAKE2b-128 over every field's name, dtype, shape and bytes in ``ScenarioBatch`` order (a
history-only view digests only its frames); ``dataset_digest``: over an ordered collection of those.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import fields

import numpy as np

from letspi.scenario.types import ScenarioBatch

_DIGEST_BYTES = 16


def _field_bytes(arr: np.ndarray, row: int) -> bytes:
    item = arr[row]
    if arr.dtype == object:
        return str(item).encode("utf-8")
    a = np.ascontiguousarray(item)
    return f"{a.dtype.str}{a.shape}".encode() + a.tobytes()


def scenario_digests(batch: ScenarioBatch) -> np.ndarray:
    """(B,) object array of 32-character hex digests, one per scenario."""
    arrays = [(f.name.encode(), getattr(batch, f.name)) for f in fields(ScenarioBatch)]
    out = np.empty(len(batch), dtype=object)
    for i in range(len(batch)):
        h = hashlib.blake2b(digest_size=_DIGEST_BYTES)
        for name, arr in arrays:
            h.update(name)
            h.update(_field_bytes(arr, i))
        out[i] = h.hexdigest()
    return out


def dataset_digest(digests: Sequence[str] | np.ndarray) -> str:
    """Digest of an ordered collection of scenario digests (order matters: rows are positions)."""
    h = hashlib.blake2b(digest_size=_DIGEST_BYTES)
    for d in digests:
        h.update(str(d).encode("ascii"))
    return h.hexdigest()
