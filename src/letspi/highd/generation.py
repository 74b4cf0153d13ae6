"""``NN_generation.json``: how a generated recording was made (a letspi extension; real HighD has none).

letspi's SUMO generator writes one per recording (seed, minutes, lanes, flow, the traffic configuration, the
accepted attempt, letspi version); scenario extraction copies it into the scenario file's provenance.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from letspi.fsutil import atomic_write_text

__all__ = ["generation_file", "read_generation", "write_generation"]


def generation_file(recording_id: int) -> str:
    return f"{recording_id:02d}_generation.json"


def write_generation(record: dict[str, Any], directory: Path, recording_id: int) -> Path:
    """Write ``NN_generation.json`` (``record`` must hold an integer ``seed``)."""
    if not isinstance(record.get("seed"), int):
        raise ValueError(f"a generation record needs an integer 'seed', got {record.get('seed')!r}")
    return atomic_write_text(Path(directory) / generation_file(recording_id),
                             json.dumps(record, indent=2, sort_keys=True) + "\n")


def read_generation(directory: Path, recording_id: int) -> dict[str, Any] | None:
    """``NN_generation.json`` of a recording, or None when there is none; ValueError naming the file when it is not
    a JSON object with an integer ``seed``."""
    path = Path(directory) / generation_file(recording_id)
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(record, dict) or not isinstance(record.get("seed"), int):
        raise ValueError(f"{path}: expected a JSON object with an integer 'seed'")
    return record
