"""letspi.arrays: the batch mixins of the array dataclasses (len from the first field, take by rows)."""

from __future__ import annotations

from dataclasses import FrozenInstanceError, dataclass

import numpy as np
import pytest

from letspi.arrays import Batched, Rows
from letspi.learned.features import SceneFeatures
from letspi.method.memory import MemoryFeatures


@dataclass(frozen=True)
class _Pair(Rows):
    xy_m: np.ndarray  # (B, 2)
    valid: np.ndarray  # (B,)

    def __post_init__(self) -> None:
        if len(self.xy_m) != len(self.valid):
            raise ValueError("rows differ")


@dataclass(frozen=True)
class _Last(Batched):
    speed_mps: np.ndarray  # (B,)
    per_step: np.ndarray  # (F, B): batch axis last


def test_len_is_the_first_fields_rows_and_take_keeps_rows_of_every_field() -> None:
    pair = _Pair(np.arange(10.0).reshape(5, 2), np.array([True, False, True, True, False]))
    assert len(pair) == 5 and len(_Last(np.zeros(3), np.zeros((7, 3)))) == 3
    for rows, expect in (([3, 0], [3, 0]), (pair.valid, [0, 2, 3]), (slice(1, 3), [1, 2])):
        sub = pair.take(rows)
        assert isinstance(sub, _Pair) and len(sub) == len(expect)
        np.testing.assert_array_equal(sub.xy_m[:, 0], 2.0 * np.array(expect))
        np.testing.assert_array_equal(sub.valid, pair.valid[expect])
    assert len(pair.take(np.array([], dtype=np.int64))) == 0
    with pytest.raises(FrozenInstanceError):
        pair.take([0]).xy_m = np.zeros((1, 2))  # type: ignore[misc]


def test_the_batch_records_of_the_package_take_their_rows() -> None:
    feats = SceneFeatures(np.zeros((4, 3, 15, 5)), np.zeros((4, 3, 6)), np.ones((4, 3), bool),
                          np.arange(4.0)[:, None] * np.ones((4, 22)), np.zeros((4, 2)))
    sub = feats.take(np.array([2, 3]))
    assert len(sub) == 2 and sub.lane[:, 0].tolist() == [2.0, 3.0] and sub.agent_hist.shape == (2, 3, 15, 5)
    mem = MemoryFeatures(np.array([5, 7, 9]), np.zeros((3, 6)), np.array(["a", "b", "c"], dtype=object),
                         np.array([1, 2, 3]), np.array([10, 20, 30]))
    picked = mem.take(mem.ids > 5)
    assert picked.ids.tolist() == [7, 9] and picked.recording_key.tolist() == ["b", "c"]
    assert picked.frame0.tolist() == [20, 30]
