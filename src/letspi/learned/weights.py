"""Weight files of the learned models: a directory of ``weights.npz`` (float32 arrays by ``state_dict`` names) and
``manifest.json`` (kind, format version, config, data, validation metrics, training command)."""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from letspi.fsutil import provenance_record

FORMAT_VERSION = 1
WEIGHTS_FILE = "weights.npz"
MANIFEST_FILE = "manifest.json"


class WeightsError(ValueError):
    """A model directory is missing, incomplete or of the wrong kind."""


def save_weights(out_dir: Path, arrays: dict[str, np.ndarray], manifest: dict[str, Any]) -> Path:
    """Write ``arrays`` (float32) and ``manifest`` (plus ``format_version``) to ``out_dir`` via temporaries and
    renames (a crash leaves no half-written pair); returns ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp_w = out / (WEIGHTS_FILE + ".tmp.npz")
    np.savez_compressed(tmp_w, **{k: np.asarray(v, dtype=np.float32) for k, v in arrays.items()})  # type: ignore[arg-type]
    record = provenance_record({"format_version": FORMAT_VERSION, **manifest})  # no directory of this machine
    tmp_m = out / (MANIFEST_FILE + ".tmp")
    tmp_m.write_text(json.dumps(record, indent=2, allow_nan=True, default=_json_default) + "\n")
    os.replace(tmp_w, out / WEIGHTS_FILE)
    os.replace(tmp_m, out / MANIFEST_FILE)
    return out


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def load_weights(model_dir: Path, expected_model: str | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Arrays (float64) and manifest from ``model_dir``; ``WeightsError`` when missing or mismatched."""
    d = Path(model_dir)
    wfile, mfile = d / WEIGHTS_FILE, d / MANIFEST_FILE
    if not wfile.is_file() or not mfile.is_file():
        raise WeightsError(f"{d}: no trained model here (expected {WEIGHTS_FILE} and {MANIFEST_FILE}; "
                           "create them with `letspi train goals|gnp`)")
    try:
        manifest = json.loads(mfile.read_text())
    except json.JSONDecodeError as exc:
        raise WeightsError(f"{mfile}: invalid JSON ({exc})") from exc
    if manifest.get("format_version") != FORMAT_VERSION:
        raise WeightsError(f"{mfile}: format_version {manifest.get('format_version')!r}, expected {FORMAT_VERSION}")
    if expected_model is not None and manifest.get("model") != expected_model:
        raise WeightsError(f"{d}: holds a {manifest.get('model')!r} model, expected {expected_model!r}")
    with np.load(wfile) as npz:
        arrays = {k: npz[k].astype(np.float64) for k in npz.files}
    return arrays, manifest


def shipped_weights_dir(model: str) -> Path:
    """Directory of the weights shipped in the package for ``model`` ("goal" or "gnp")."""
    return Path(str(resources.files("letspi.data").joinpath("weights", model)))
