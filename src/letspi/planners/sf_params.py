"""Fitted social-force parameters on disk: the values plus the data they came from.

File format (JSON)::

    {"params": {"tau_s": ..., "k_np": ..., ...},
     "provenance": {"scenarios_file": ..., "n_train": ..., "split_seed": ..., ...},
     "objective": {...}}

The package ships one fit (``letspi/data/sf_params.json``, from ``letspi fit sf`` on generated
traffic with a different seed than the demo's); ``--sf-params FILE`` points letspi at another.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from letspi.physics.params import PARAM_NAMES, SocialForceParams

SHIPPED_FILE = "sf_params.json"


def load_sf_params(path: Path | None = None) -> tuple[SocialForceParams, dict[str, object]]:
    """Parameters and the whole record from ``path`` (default: the shipped fit)."""
    if path is None:
        text = resources.files("letspi.data").joinpath(SHIPPED_FILE).read_text()
        where = f"letspi/data/{SHIPPED_FILE}"
    else:
        try:
            text = Path(path).read_text()
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"{path}: no such SF parameter file (create one with `letspi fit sf`)") from exc
        where = str(path)
    try:
        record = json.loads(text)
        values = record["params"]
        missing = [n for n in PARAM_NAMES if n not in values]
        if missing:
            raise ValueError(f"missing parameter(s) {missing}")
        params = SocialForceParams.from_mapping({n: float(values[n]) for n in PARAM_NAMES})
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: not a valid SF parameter file ({exc})") from exc
    return params, record


def save_sf_params(path: Path, params: SocialForceParams, provenance: dict[str, object],
                   objective: dict[str, object]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"params": params.as_dict(), "provenance": provenance, "objective": objective}
    path.write_text(json.dumps(record, indent=2) + "\n")
    return path
