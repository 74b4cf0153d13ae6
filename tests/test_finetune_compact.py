"""The compact prompt of the fine-tuned model, its configuration identity, and the adapter export mapping."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from letspi.assembly.resolve import Resolver
from letspi.llm.backends.llamacpp_open import open_vocab
from letspi.llm.compact import (
    compact_reply_text,
    compact_report_text,
    compact_scene_text,
    compact_system_prompt,
    render_compact_prompt,
)
from letspi.llm.describe import describe_scenario
from letspi.llm.models import ADAPTER_ENV, locate_model
from letspi.llm.parse import parse_reply
from letspi.llm.schema import DEFAULT_REPLY, NUMERIC_FIELDS, WIRE_KEYS
from letspi.llm.types import ModelNotFoundError
from letspi.planners.options import PlannerOptions
from letspi.scenario.build import VehicleSpec, straight_road_scenario

pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.finetune.export import (
    AdapterExportError,
    adapter_tensors,
    gguf_lora_name,
    permute_rotary_rows,
)

LABEL = {"tau_s": 1.234, "k_np": 31.26, "k_nf": 9.04, "k_nl": 0.5, "k_boundary": 1.0, "k_cline": 0.33,
         "lon_factor": 0.6, "lane_factor": -0.0}


def _busy_desc():  # type: ignore[no-untyped-def]
    nbrs = [VehicleSpec(25.0, 24.0), VehicleSpec(-30.0, 33.0), VehicleSpec(2.0, 30.0, lane_offset=1)]
    nbrs += [VehicleSpec(float(x), 30.0, lane_offset=off) for x, off in ((-60, -1), (-40, 1), (45, -1), (70, 1),
                                                                          (90, -1))]
    return describe_scenario(straight_road_scenario(neighbours=nbrs), (150.0, 0.0))


def test_compact_prompt_states_the_scene_without_examples() -> None:
    msgs = render_compact_prompt(_busy_desc())
    assert [m["role"] for m in msgs] == ["system", "user"]
    assert msgs[0]["content"] == compact_system_prompt()  # static: a prefix llama.cpp reuses
    user = msgs[1]["content"]
    assert "Example" not in user and "Answer:" not in user and "Rejected" not in user
    assert "\nahead dx 25 rel -6.0 gap 20 TTC 3.4\n" in user  # same lane: gap and TTC
    assert "left-alongside dx 2 dy 4 rel 0.0" in user and "Goal at 5 s: dx 150 dy 0, same lane." in user
    assert "Cars 6 of 8" in user  # bounded: the nearest six
    assert "Cars 3 of 8" in compact_scene_text(_busy_desc(), max_neighbours=3)
    assert all(WIRE_KEYS[f] in msgs[0]["content"] for f in NUMERIC_FIELDS)


def test_refine_prompt_carries_the_rejected_answer_and_the_check_facts() -> None:
    report = compact_report_text({"min_ttc_s": 0.8, "min_rear_ttc_s": None, "min_path_gap_m": float("inf"),
                                  "min_box_gap_m": 1.25, "collision": True}, ["contact", "ttc", "contact"])
    assert report == "front TTC 0.8, rear TTC -, gap -, contact yes; failed contact, ttc."
    msgs = render_compact_prompt(_busy_desc(), rejected=LABEL, report=report)
    assert "Rejected: tau 1.2 k_np 31 k_nf 9 k_nl 0.5 k_bd 1.0 k_cl 0.3 lon 0.6 lane 0.0" in msgs[1]["content"]
    assert report in msgs[1]["content"]
    with pytest.raises(ValueError, match="both"):
        render_compact_prompt(_busy_desc(), rejected=LABEL)


def test_compact_reply_is_the_fast_wire_format_with_few_decimals() -> None:
    text = compact_reply_text(LABEL)
    assert text == '{"tau": 1.2, "k_np": 31, "k_nf": 9, "k_nl": 0.5, "k_bd": 1.0, "k_cl": 0.3, "lon": 0.6, "lane": 0.0}'
    parsed = parse_reply(text)
    assert parsed.reply.k_np == 31 and parsed.reply.lon_factor == pytest.approx(0.6)
    assert not parsed.clamped
    assert json.loads(compact_reply_text(DEFAULT_REPLY))["tau"] == DEFAULT_REPLY.tau_s


def test_compact_prompt_fits_400_smollm2_tokens() -> None:
    pytest.importorskip("llama_cpp")

    try:
        path = locate_model("smollm2-135m")
    except Exception as exc:  # the model package is optional in some environments
        pytest.skip(str(exc))
    vocab = open_vocab(path)
    report = compact_report_text({"min_ttc_s": 0.8, "min_rear_ttc_s": 0.5, "min_path_gap_m": -1.0,
                                  "min_box_gap_m": 0.0, "collision": True}, ["contact", "rear_ttc", "in_path_gap"])
    for msgs in (render_compact_prompt(_busy_desc()), render_compact_prompt(_busy_desc(), rejected=LABEL,
                                                                             report=report)):
        text = "".join(f"<|im_start|>{m['role']}\n{m['content']}<|im_end|>\n" for m in msgs)
        text += "<|im_start|>assistant\n"
        n = len(vocab.tokenize(text.encode(), add_bos=False, special=True))
        assert 100 < n <= 400, n
    vocab.close()


def test_fine_tuned_model_uses_the_compact_prompt_and_its_adapter_enters_the_key(tmp_path: Path) -> None:
    try:
        locate_model("smollm2-135m")
    except Exception as exc:
        pytest.skip(str(exc))
    a, b = tmp_path / "a.gguf", tmp_path / "b.gguf"
    a.write_bytes(b"adapter one")
    b.write_bytes(b"adapter two")
    opts = PlannerOptions(llm="llamacpp:smollm2-135m-letspi")
    ca = Resolver(opts, env={ADAPTER_ENV: str(a)}).llm("llamacpp:smollm2-135m-letspi")
    cb = Resolver(opts, env={ADAPTER_ENV: str(b)}).llm("llamacpp:smollm2-135m-letspi")
    assert ca.prompt_style == "compact" and ca.adapter_path == str(a)
    assert ca.model_sha256 == cb.model_sha256 and ca.key() != cb.key()  # same base, another adapter
    base = Resolver(opts, env={}).llm("llamacpp:smollm2-135m")
    assert base.prompt_style == "paper" and base.adapter_sha256 is None
    forced = Resolver(PlannerOptions(prompt_style="compact"), env={}).llm("llamacpp:smollm2-135m")
    assert forced.prompt_style == "compact" and forced.key() != base.key()
    with pytest.raises(ModelNotFoundError, match=ADAPTER_ENV):
        Resolver(opts, env={ADAPTER_ENV: str(tmp_path / "missing.gguf")}).llm("llamacpp:smollm2-135m-letspi")


def test_peft_names_map_to_llama_cpp_adapter_names() -> None:
    assert gguf_lora_name("base_model.model.model.layers.3.self_attn.q_proj.lora_A.weight") == \
        "blk.3.attn_q.weight.lora_a"
    assert gguf_lora_name("base_model.model.model.layers.12.mlp.down_proj.lora_B.weight") == \
        "blk.12.ffn_down.weight.lora_b"
    assert gguf_lora_name("model.layers.0.self_attn.o_proj.lora_B.default.weight") == \
        "blk.0.attn_output.weight.lora_b"
    for bad in ("base_model.model.lm_head.lora_A.weight", "base_model.model.model.embed_tokens.lora_A.weight"):
        with pytest.raises(AdapterExportError, match="not adapted"):
            gguf_lora_name(bad)


def test_rotary_permutation_is_what_transformers_undoes_and_only_touches_q_k_lora_b() -> None:
    from letspi_train.finetune.export import _tensor_order  # ordering by layer, then name

    rng = np.random.default_rng(0)
    n_head, n_kv, head_dim, hidden, rank = 3, 1, 4, 12, 2
    q_b = rng.normal(size=(n_head * head_dim, rank)).astype(np.float32)
    permuted = permute_rotary_rows(q_b, n_head)
    # transformers' GGUF loader: w.reshape(n_head, dim, 2, ...).swapaxes(2, 1) (the inverse)
    undone = permuted.reshape(n_head, head_dim // 2, 2, rank).swapaxes(2, 1).reshape(q_b.shape)
    np.testing.assert_array_equal(undone, q_b)
    assert not np.array_equal(permuted, q_b)

    pre = "base_model.model.model.layers.0."
    state = {
        pre + "self_attn.q_proj.lora_A.weight": rng.normal(size=(rank, hidden)),
        pre + "self_attn.q_proj.lora_B.weight": q_b,
        pre + "self_attn.k_proj.lora_A.weight": rng.normal(size=(rank, hidden)),
        pre + "self_attn.k_proj.lora_B.weight": rng.normal(size=(n_kv * head_dim, rank)),
        pre + "self_attn.v_proj.lora_A.weight": rng.normal(size=(rank, hidden)),
        pre + "self_attn.v_proj.lora_B.weight": rng.normal(size=(n_kv * head_dim, rank)),
    }
    out = adapter_tensors(state, n_head=n_head, n_kv_head=n_kv)
    np.testing.assert_array_equal(out["blk.0.attn_q.weight.lora_b"], permuted)
    np.testing.assert_allclose(out["blk.0.attn_k.weight.lora_b"],
                               permute_rotary_rows(state[pre + "self_attn.k_proj.lora_B.weight"], n_kv), rtol=1e-6)
    v_b, q_a = state[pre + "self_attn.v_proj.lora_B.weight"], state[pre + "self_attn.q_proj.lora_A.weight"]
    np.testing.assert_allclose(out["blk.0.attn_v.weight.lora_b"], v_b, rtol=1e-6)
    np.testing.assert_allclose(out["blk.0.attn_q.weight.lora_a"], q_a, rtol=1e-6)
    assert out["blk.0.attn_q.weight.lora_a"].dtype == np.float32
    assert list(out) == sorted(out, key=_tensor_order)
    # the product B @ A (what llama.cpp adds to q) has its output rows in the GGUF order
    delta = out["blk.0.attn_q.weight.lora_b"] @ out["blk.0.attn_q.weight.lora_a"]
    np.testing.assert_allclose(delta, permute_rotary_rows(q_b @ state[pre + "self_attn.q_proj.lora_A.weight"], 3),
                               rtol=1e-4, atol=1e-5)
    with pytest.raises(AdapterExportError, match="no matching"):
        adapter_tensors({pre + "self_attn.q_proj.lora_A.weight": state[pre + "self_attn.q_proj.lora_A.weight"]},
                        n_head=n_head, n_kv_head=n_kv)


def test_adapter_gguf_round_trip(tmp_path: Path) -> None:
    pytest.importorskip("gguf")
    from letspi_train.finetune.export import read_adapter_gguf, write_adapter_gguf

    rng = np.random.default_rng(1)
    tensors = {"blk.0.attn_v.weight.lora_a": rng.normal(size=(2, 6)).astype(np.float32),
               "blk.0.attn_v.weight.lora_b": rng.normal(size=(4, 2)).astype(np.float32)}
    path = write_adapter_gguf(tmp_path / "adapter.gguf", tensors, alpha=16)
    meta, back = read_adapter_gguf(path)
    assert meta == {"general.architecture": "llama", "general.type": "adapter", "adapter.type": "lora",
                    "adapter.lora.alpha": 16.0}
    for name, arr in tensors.items():
        np.testing.assert_array_equal(back[name], arr)
