"""The preference step's pieces (pairs ranked in hindsight, the DPO loss) and the rebalanced supervised split."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from letspi.analysis.options import OptionOutcomes
from letspi.cli.app import app
from letspi.method.decide import load_presets
from letspi.scenario.build import VehicleSpec, straight_road_scenario
from letspi.scenario.identity import scenario_digests
from letspi.scenario.store import save_scenarios
from letspi.scenario.types import concat_batches

pytest.importorskip("letspi_train", reason="letspi-train is not installed (pip install -e packages/letspi-train)")
from letspi_train.finetune.data import ChatExample
from letspi_train.finetune.decide_data import CHOICE_FORMAT, ChoiceLabel, label_frame
from letspi_train.finetune.preference import dpo_loss, hindsight_utility, hindsight_verdict, ranked_pairs
from letspi_train.finetune.train import rebalance

W = {"at_fault": 8.0, "contact": 2.0, "progress_per_m": 0.01}
NAMES = ("default", "ease", "slow", "brake")


def test_the_best_preset_in_hindsight_is_preferred_to_each_one_whose_outcome_is_worse() -> None:
    # [at_fault, contact, success, progress_m]: the defaults collide at fault; ease avoids it and succeeds;
    # slow avoids it but misses the endpoint; brake the same with less progress
    h = np.array([[1, 1, 1, 120.0], [0, 0, 1, 110.0], [0, 0, 0, 100.0], [0, 0, 0, 80.0]])
    u = hindsight_utility(h, W)
    np.testing.assert_allclose(u, [-8 - 2 + 1, 1 - 0.1, -0.2, -0.4])
    assert ranked_pairs(NAMES, h, W, margin=1.0) == [("ease", "default"), ("ease", "slow"), ("ease", "brake")]
    assert ranked_pairs(NAMES, h, W, margin=2.0) == [("ease", "default")]
    calm = np.array([[0, 0, 1, 120.0], [0, 0, 1, 110.0], [0, 0, 1, 100.0], [0, 0, 1, 80.0]])
    assert ranked_pairs(NAMES, calm, W, margin=1.0) == []  # progress alone makes no pair


def test_an_answer_is_judged_against_its_label_by_outcome_not_progress() -> None:
    h = np.array([[1, 1, 1, 120.0], [0, 0, 1, 110.0], [0, 0, 0, 100.0], [0, 0, 0, 80.0]])
    assert hindsight_verdict(h, W, label=2, answer=3) == "same_outcome"  # 20 m less progress: the same outcome
    assert hindsight_verdict(h, W, label=2, answer=1) == "better"  # succeeds where the label misses the endpoint
    assert hindsight_verdict(h, W, label=1, answer=0) == "worse"  # at fault where the label is safe
    # a contact that is not at fault and a success (-2 + 1) is worse than neither (0)
    mixed = np.array([[0, 1, 1, 150.0], [0, 0, 0, float("nan")]])
    assert hindsight_verdict(mixed, W, label=1, answer=0) == "worse"
    assert hindsight_verdict(mixed, W, label=0, answer=1) == "better"


def test_the_dpo_loss_is_the_log_sigmoid_of_the_scaled_margin_over_the_reference() -> None:
    torch = pytest.importorskip("torch")
    pc, pr = torch.tensor([-1.0, -2.0]), torch.tensor([-3.0, -1.0])
    rc, rr = torch.tensor([-2.0, -2.0]), torch.tensor([-2.0, -2.0])
    # margins: (1 - (-1)) = 2 and (0 - 1) = -1; beta 0.5 -> 1.0 and -0.5
    expected = (math.log1p(math.exp(-1.0)) + math.log1p(math.exp(0.5))) / 2
    assert float(dpo_loss(pc, pr, rc, rr, 0.5)) == pytest.approx(expected, rel=1e-6)
    same = dpo_loss(rc, rr, rc, rr, 0.1)  # the policy equals the reference: log 2
    assert float(same) == pytest.approx(math.log(2.0), rel=1e-6)


def test_rebalancing_repeats_the_examples_of_rare_replies() -> None:
    def ex(reply: str, i: int) -> ChatExample:
        return ChatExample((), reply, "propose", f"d{i}")

    examples = [ex("a", i) for i in range(16)] + [ex("b", 16 + i) for i in range(4)] + [ex("c", 20)]
    assert rebalance(examples, 0.0) == examples
    even = rebalance(examples, 1.0)
    counts = {r: sum(e.reply == r for e in even) for r in "abc"}
    assert counts == {"a": 16, "b": 16, "c": 8}  # 16/1 = 16 copies capped at 8
    half = rebalance(examples, 0.5)
    assert {r: sum(e.reply == r for e in half) for r in "abc"} == {"a": 16, "b": 8, "c": 4}
    assert [e.scenario_digest for e in half[16:18]] == ["d16", "d16"]  # copies stay together, in order


def _choice_labels(tmp_path: Path) -> Path:
    """A choice labels directory (``letspi train decide``'s format, with hindsight) of three straight-road
    windows where ``brake`` is best in hindsight (the only success; equal progress, so it leads every other
    preset by the margin of 1) and ``default`` collides."""
    batch = concat_batches([
        straight_road_scenario(ego_speed_mps=33.0, neighbours=[VehicleSpec(x0_m=30.0 + 5 * i, speed_mps=20.0)],
                               scenario_id=f"w{i}") for i in range(3)])
    scen = save_scenarios(batch, tmp_path / "train.arrow")
    digests = [str(d) for d in scenario_digests(batch)]
    presets = load_presets()[0]
    b, k = len(batch), len(presets)
    collide = np.zeros((b, k), bool)
    collide[:, 0] = True
    success = np.zeros((b, k), bool)
    success[:, presets.index("brake")] = True
    o = OptionOutcomes(collision=collide, at_fault=collide.copy(), success=success, min_ttc_s=np.full((b, k), 9.0),
                       progress_m=np.full((b, k), 110.0), predicted_safe=np.ones((b, k), bool),
                       adverse_failed=np.zeros((b, k, 3), bool), adverse_applies=np.zeros((b, 3), bool))
    labels = [ChoiceLabel(i, presets.index("ease"), 1.0, 0.3) for i in range(b)]
    frame = label_frame(labels, o, presets, ("leader-brakes", "cut-in", "follower-keeps"), digests)
    out = tmp_path / "labels"
    out.mkdir()
    frame.to_parquet(out / "labels.parquet")
    (out / "manifest.json").write_text(json.dumps({
        "format": CHOICE_FORMAT, "scenarios_path": str(scen), "presets": list(presets.names),
        "weights": {"at_fault": 8.0, "contact": 2.0, "progress_per_m": 0.01}, "dataset_digest": "x"}))
    return out


@pytest.mark.slow
def test_a_few_dpo_steps_from_a_supervised_adapter_lower_the_preference_loss(tmp_path: Path) -> None:
    pytest.importorskip("peft")
    pytest.importorskip("llama_cpp")
    labels = _choice_labels(tmp_path)
    sft, dpo = tmp_path / "sft", tmp_path / "dpo"
    res = CliRunner().invoke(app, ["train", "llm", "--data", str(labels), "--out", str(sft), "--max-steps", "2",
                                   "--batch-size", "2", "--rank", "4", "--val-fraction", "0", "--verify", "0",
                                   "--layers", "2"])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["train", "dpo", "--data", str(labels), "--init", str(sft), "--out", str(dpo),
                                   "--lr", "2e-3", "--epochs", "4", "--batch-size", "2", "--beta", "0.5"])
    assert res.exit_code == 0, res.output
    manifest = json.loads((dpo / "manifest.json").read_text())
    # per window: brake (the only success, no contact) is preferred to each of the other five presets
    assert manifest["data"]["n_pairs_train"] + manifest["data"]["n_pairs_val"] == 3 * 5
    t = manifest["training"]
    assert t["first_loss"] == pytest.approx(math.log(2.0), abs=0.1)  # the policy starts as its reference
    assert t["final_loss_mean10"] < t["first_loss"]
    assert (dpo / "adapter.gguf").is_file() and manifest["prompt_style"] == "choice"
