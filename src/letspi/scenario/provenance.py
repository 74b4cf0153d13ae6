"""Where a scenario file's traffic came from, and the generator seeds the benchmark suites reserve.

A scenario file's provenance records the ``NN_generation.json`` (with the generator seed) of every generated
recording it was cut from; the commands that fit or label on scenarios refuse files made from ``SUITE_SEEDS``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from letspi.highd.generation import read_generation

__all__ = ["SUITE_SEEDS", "generation_records", "generator_seeds", "refuse_suite_traffic"]

#: traffic generator seeds reserved for the benchmark suites (``letspi.benchmark``)
SUITE_SEEDS: Final = range(1000, 2000)


def generation_records(directory: Path, recording_ids: Sequence[int]) -> list[dict[str, Any]]:
    """The ``NN_generation.json`` of each of ``recording_ids`` that has one, with its ``recording`` id."""
    records = []
    for rid in recording_ids:
        record = read_generation(directory, rid)
        if record is not None:
            records.append({**record, "recording": rid})
    return records


def generator_seeds(meta: Mapping[str, object]) -> list[int]:
    """The generator seeds a scenario file's traffic was made from (sorted, unique; [] when not recorded)."""
    provenance = meta.get("provenance")
    if not isinstance(provenance, Mapping):
        return []
    records = provenance.get("generation") or []
    return sorted({int(r["seed"]) for r in records if isinstance(r, Mapping) and isinstance(r.get("seed"), int)})


def refuse_suite_traffic(path: Path, meta: Mapping[str, object]) -> None:
    """Raise when the scenario file ``path`` (its metadata ``meta``) was cut from benchmark-suite traffic."""
    reserved = [s for s in generator_seeds(meta) if s in SUITE_SEEDS]
    if reserved:
        raise ValueError(f"{path}: made from traffic generator seed(s) {', '.join(map(str, reserved))}, reserved for "
                         f"the benchmark suites ({SUITE_SEEDS.start}-{SUITE_SEEDS.stop - 1}); fit and train on "
                         "traffic of other seeds")
