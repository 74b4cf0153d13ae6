"""fsutil.resume_directory: the settings a resumable output directory pins, and what a rerun finds there."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from letspi.fsutil import SETTINGS_FILE, resume_directory


def test_a_fresh_run_pins_its_settings_and_a_rerun_resumes_or_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "labels"
    parts, fresh = resume_directory(out, {"seed": 1, "search": {"n": 4}}, what="labels", instead="use another --out")
    assert fresh and parts == out / "parts" and parts.is_dir()
    assert json.loads((out / SETTINGS_FILE).read_text()) == {"search": {"n": 4}, "seed": 1}
    (parts / ".part-000000.npz.1a2b3c4d.tmp").write_text("torn")  # what a killed writer leaves
    (out / ".manifest.json.5e6f7a8b.tmp").write_text("torn")
    (parts / "part-000000.npz").write_text("kept")
    assert resume_directory(out, {"seed": 1, "search": {"n": 4}}, what="labels",
                            instead="use another --out") == (parts, False)
    assert sorted(p.name for p in parts.iterdir()) == ["part-000000.npz"]
    assert not list(out.glob(".*.tmp"))
    with pytest.raises(ValueError, match=r"labels: holds labels made with other settings \(search, seed\); "
                                         r"use another --out or delete it"):
        resume_directory(out, {"seed": 2, "search": {"n": 5}}, what="labels", instead="use another --out")
    assert json.loads((out / SETTINGS_FILE).read_text())["seed"] == 1  # nothing touched
