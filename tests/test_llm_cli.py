"""``letspi llm`` sub-app (typer) with the scripted backend."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from letspi.cli.llm import app

runner = CliRunner()


def test_check_scripted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LETSPI_CACHE_DIR", str(tmp_path))
    res = runner.invoke(app, ["check", "scripted:default"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["fallback"] is False and out["reply"]["k_np"] == 25.0 and out["model_spec"] == "scripted:default"
    res = runner.invoke(app, ["check", "scripted:default", "--prompt", "physics", "--no-cache"])
    assert res.exit_code == 0 and json.loads(res.stdout)["prompt"] == "physics"


def test_check_bad_spec_exits_2() -> None:
    res = runner.invoke(app, ["check", "hf:gpt2", "--no-cache"])
    assert res.exit_code == 2 and "Valid forms" in res.output


def test_models_lists_embedded() -> None:
    res = runner.invoke(app, ["models"])
    assert res.exit_code == 0
    specs = {row["spec"] for row in json.loads(res.stdout)}
    assert specs == {"llamacpp:gemma3-270m", "llamacpp:smollm2-135m", "llamacpp:smollm2-135m-letspi"}
