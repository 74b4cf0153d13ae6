"""The shipped fine-tuned model (``llamacpp:smollm2-135m-letspi``): its adapter is the one its manifest
describes, it loads on top of the packaged base, and it answers the standard scene validly."""

from __future__ import annotations

import json

import pytest

from letspi.assembly.resolve import file_sha256
from letspi.bench.llm_runtime import standard_messages
from letspi.llm.client import ParamAdvisor
from letspi.llm.models import ADAPTER_FILE, locate_adapter, locate_model, shipped_adapter_dir
from letspi.llm.schema import FIELD_RANGES, NUMERIC_FIELDS
from letspi.planners.llm import DEFAULT_FAST_LLM, DEFAULT_LLM

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
    assert file_sha256(locate_model("smollm2-135m")) == manifest["base_model"]["sha256"]
    assert locate_adapter("smollm2-135m-letspi", env={}) == adapter
    assert manifest["prompt_style"] == "compact"
    # trained as the issue asks: >= 2 epochs over >= 1,500 training examples, split by ego vehicle
    assert manifest["training"]["epochs_done"] >= 2.0 and manifest["data"]["n_train"] >= 1500
    assert manifest["data"]["split"].startswith("by ego vehicle")
    assert manifest["training"]["val_loss_after"] < manifest["training"]["val_loss_before"]


def test_shipped_adapter_answers_the_standard_scene_validly() -> None:
    pytest.importorskip("llama_cpp")
    advisor = ParamAdvisor("llamacpp:smollm2-135m-letspi", cache=None)
    advice = advisor.advise(standard_messages(), variant="fast")
    assert not advice.fallback and len(advice.attempts) == 1 and advice.attempts[0].ok
    values = {f: float(getattr(advice.reply, f)) for f in NUMERIC_FIELDS}
    assert not advice.clamped
    for f, v in values.items():
        low, high = FIELD_RANGES[f]
        assert low <= v <= high, (f, v)
    # non-degenerate: the leader 15 m ahead closing at 8 m/s is pushed back, the relaxation time is not
    # at a bound (the base model's zero-shot answer is every repulsion 0 and tau at its lower bound)
    assert values["k_np"] > 0.0
    assert FIELD_RANGES["tau_s"][0] < values["tau_s"] < FIELD_RANGES["tau_s"][1]
