"""The shipped fine-tuned model (``llamacpp:smollm2-135m-letspi``): its adapter is the one its manifest
describes, it loads on top of the packaged base, and it answers the choice prompt (issue 28: it picks one
of the decision step's presets) of the standard scene validly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from letspi.assembly.resolve import file_sha256
from letspi.llm.choice import OptionLine, render_choice_prompt
from letspi.llm.client import ParamAdvisor
from letspi.llm.describe import describe_scenario
from letspi.llm.models import (
    ADAPTER_FILE,
    adapter_prompt_style,
    locate_adapter,
    locate_model,
    packaged_smollm2_path,
    shipped_adapter_dir,
)
from letspi.method.decide import load_presets
from letspi.planners.llm import DEFAULT_FAST_LLM, DEFAULT_LLM
from letspi.scenario.build import VehicleSpec, straight_road_scenario

MAX_ADAPTER_BYTES = 10_000_000


def _manifest() -> dict:
    return json.loads((shipped_adapter_dir() / "manifest.json").read_text())


def test_the_fine_tuned_model_is_the_default_of_both_phases() -> None:
    assert DEFAULT_LLM == DEFAULT_FAST_LLM == "llamacpp:smollm2-135m-letspi"


def test_shipped_adapter_matches_its_manifest_and_base() -> None:
    adapter = shipped_adapter_dir() / ADAPTER_FILE
    manifest = _manifest()
    assert adapter.stat().st_size <= MAX_ADAPTER_BYTES
    assert file_sha256(adapter) == manifest["adapter"]["sha256"]
    assert manifest["adapter"]["bytes"] == adapter.stat().st_size
    assert file_sha256(packaged_smollm2_path()) == manifest["base_model"]["sha256"]  # trained on the packaged file
    assert locate_model("smollm2-135m").name.startswith(Path(manifest["base_model"]["path"]).stem)  # run as its copy
    assert locate_adapter("smollm2-135m-letspi", env={}) == adapter
    assert manifest["prompt_style"] == "choice"
    # two epochs of 8-example steps over >= 5,000 training examples rebalanced towards the rare presets, split
    # by ego vehicle, and it learned (validation loss)
    assert manifest["training"]["epochs_done"] >= 2.0 and manifest["data"]["n_train"] >= 5000
    assert manifest["hyperparameters"]["balance"] == 0.5 and "resumed" in manifest["training"]["note"]
    assert manifest["data"]["split"].startswith("by ego vehicle")
    assert manifest["training"]["val_loss_after"] < 0.2 * manifest["training"]["val_loss_before"]


def test_the_shipped_adapter_sets_the_choice_prompt_style() -> None:
    assert adapter_prompt_style(shipped_adapter_dir() / ADAPTER_FILE) == "choice"


def test_shipped_adapter_picks_a_preset_for_the_standard_scene() -> None:
    pytest.importorskip("llama_cpp")
    names = list(load_presets()[0].names)
    batch = straight_road_scenario(neighbours=[VehicleSpec(x0_m=15.0, speed_mps=22.0),
                                               VehicleSpec(x0_m=-25.0, speed_mps=31.0, lane_offset=1)],
                                   scenario_id="standard")
    lines = [OptionLine(n, ("predicted", "leader-brakes") if n == "default" else (), 140.0 - 8 * i)
             for i, n in enumerate(names)]
    messages = render_choice_prompt(describe_scenario(batch, (150.0, 0.0)), lines, risk=0.4)
    advice = ParamAdvisor("llamacpp:smollm2-135m-letspi", cache=None).choose(messages, {n: n for n in names})
    assert not advice.fallback and len(advice.attempts) == 1 and advice.attempts[0].ok
    assert advice.choice in names
