"""One preference step after supervised tuning: DPO on pairs of presets ranked by their hindsight outcome.

For every window of the choice labels (``letspi train decide``: the ``hindsight_json`` column, per preset
the at-fault contact, contact, success and progress of its plan against the recorded future), the preset
of the highest hindsight utility (the labels' weights: ``-at_fault af - contact c + success + progress_per_m
(progress - the defaults')``) is preferred to each preset whose utility is lower by at least ``margin``
(an outcome differs, not only progress): ``PreferencePair``s with the window's choice prompt.

``train_dpo`` starts from a supervised adapter (its ``peft/`` directory) and minimises the DPO loss
(Rafailov et al. 2023) ``-log sigmoid(beta ((log pi(c) - log ref(c)) - (log pi(r) - log ref(r))))`` over
the reply tokens, the reference being that adapter frozen (its log-probabilities computed once). Resumable
(``letspi_train.learned.loop.run_steps``) and exported as ``train_lora`` exports (``adapter.gguf``,
``peft/``, ``manifest.json``). Torch only (the train extra).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from letspi.fsutil import atomic_write_text, provenance_path
from letspi.llm.choice import choice_reply_text
from letspi_train.finetune.data import ChatExample, read_choice_labels, split_examples
from letspi_train.finetune.decide_data import HINDSIGHT_COLUMN
from letspi_train.finetune.train import (
    ADAPTER_FILE,
    IGNORE_INDEX,
    MANIFEST_FILE,
    MANIFEST_FORMAT,
    PEFT_DIR,
    LoraTrainConfig,
    _collate,
    _export,
    _versions,
    encode_example,
    load_base,
)

if TYPE_CHECKING:  # torch is the train extra's; the module imports without it
    from letspi_train.learned.loop import StepHistory


@dataclass(frozen=True)
class PreferencePair:
    """A choice prompt, the preferred and the rejected reply, and where it came from (the split's unit)."""

    messages: tuple[Any, ...]
    chosen: str
    rejected: str
    scenario_digest: str
    vehicle_key: str


def hindsight_utility(hindsight: np.ndarray, weights: dict[str, float]) -> np.ndarray:
    """(K,) the hindsight utility of each preset from its (K, 4) ``[at_fault, contact, success, progress_m]``."""
    h = np.asarray(hindsight, dtype=np.float64)
    progress = np.nan_to_num(h[:, 3])
    out: np.ndarray = (-weights["at_fault"] * h[:, 0] - weights["contact"] * h[:, 1] + h[:, 2]
                       + weights["progress_per_m"] * (progress - progress[0]))
    return out


def hindsight_verdict(hindsight: np.ndarray, weights: dict[str, float], label: int, answer: int) -> str:
    """How preset ``answer`` fared against preset ``label`` in one window's (K, 4) ``hindsight``:
    ``same_outcome`` (the same at-fault contact, contact and success), else ``better`` or ``worse`` by the
    utility of those outcomes (progress left out: it only breaks ties between equal outcomes)."""
    h = np.asarray(hindsight, dtype=np.float64)
    if np.array_equal(h[label, :3] != 0, h[answer, :3] != 0):
        return "same_outcome"
    outcome = hindsight_utility(h, weights) - weights["progress_per_m"] * np.nan_to_num(h[:, 3])
    return "better" if outcome[answer] > outcome[label] else "worse"


def ranked_pairs(names: Sequence[str], hindsight: np.ndarray, weights: dict[str, float],
                 margin: float) -> list[tuple[str, str]]:
    """(preferred, rejected) preset names of one window: the best in hindsight (the first on a tie) against
    each preset worse by at least ``margin``."""
    u = hindsight_utility(hindsight, weights)
    best = int(np.argmax(u))
    return [(names[best], names[k]) for k in range(len(names)) if u[best] - u[k] >= margin]


def preference_pairs(examples: Sequence[ChatExample], label_dirs: Sequence[Path], *,
                     margin: float = 1.0) -> list[PreferencePair]:
    """The pairs of the propose examples of ``examples`` (``letspi_train.finetune.data.build_examples_many`` over
    ``label_dirs``, which must carry the hindsight column), each prompt once."""
    hindsight: dict[str, np.ndarray] = {}
    names: list[str] = []
    weights: dict[str, float] = {}
    for d in label_dirs:
        df, manifest = read_choice_labels(Path(d))
        if HINDSIGHT_COLUMN not in df.columns:
            raise ValueError(f"{d}: no {HINDSIGHT_COLUMN} column (labels made before preference pairs existed: "
                             "run `letspi train decide` again)")
        names, weights = list(manifest["presets"]), dict(manifest["weights"])
        for _, row in df[df["kind"] == "propose"].iterrows():
            hindsight[str(row["scenario_digest"])] = np.asarray(json.loads(row[HINDSIGHT_COLUMN]), dtype=np.float64)
    pairs, seen = [], set()
    for e in examples:
        if e.kind != "propose" or e.scenario_digest in seen or e.scenario_digest not in hindsight:
            continue
        seen.add(e.scenario_digest)
        for good, bad in ranked_pairs(names, hindsight[e.scenario_digest], weights, margin):
            pairs.append(PreferencePair(e.messages, choice_reply_text(good), choice_reply_text(bad),
                                        e.scenario_digest, e.vehicle_key))
    return pairs


def dpo_loss(policy_chosen: Any, policy_rejected: Any, ref_chosen: Any, ref_rejected: Any, beta: float) -> Any:
    """Mean DPO loss over P pairs from (P,) summed reply log-probabilities of policy and reference."""
    import torch

    margin = (policy_chosen - ref_chosen) - (policy_rejected - ref_rejected)
    return -torch.nn.functional.logsigmoid(beta * margin).mean()


def reply_logprobs(model: Any, encoded: Sequence[tuple[list[int], list[int]]], pad_id: int) -> Any:
    """(N,) the summed log-probability of each sequence's reply tokens (labels not ``IGNORE_INDEX``)."""
    import torch

    ids, labels, mask, tail = _collate(encoded, pad_id)
    logits = model(input_ids=ids, attention_mask=mask, logits_to_keep=tail).logits[:, :-1].float()
    target = labels[:, ids.shape[1] - tail + 1:]
    logp = torch.log_softmax(logits, dim=-1)
    keep = target != IGNORE_INDEX
    picked = logp.gather(-1, torch.where(keep, target, 0).unsqueeze(-1)).squeeze(-1)
    return (picked * keep).sum(dim=1)


@dataclass(frozen=True)
class DpoConfig:
    """Settings of ``train_dpo`` (recorded in the manifest)."""

    beta: float = 0.1
    lr: float = 5e-5
    epochs: float = 1.0
    batch_size: int = 4  # pairs per optimiser step
    margin: float = 1.0
    seed: int = 0
    val_fraction: float = 0.1
    threads: int = 2
    checkpoint_every_s: float = 300.0
    max_pairs: int | None = None  # at most this many training pairs (seeded sample)

    def __post_init__(self) -> None:
        if self.beta <= 0 or self.lr <= 0 or self.epochs <= 0 or self.batch_size < 1:
            raise ValueError("--beta, --lr, --epochs and --batch-size must be positive")


def train_dpo(pairs: Sequence[PreferencePair], config: DpoConfig, base_gguf: Path, init_dir: Path, out_dir: Path, *,
              data_info: dict[str, Any] | None = None, progress: Callable[[int, int, float], None] | None = None,
              command: str = "") -> dict[str, Any]:
    """DPO from the supervised adapter in ``init_dir`` (``letspi train llm``'s output) into ``out_dir``;
    returns the manifest (module docstring). Validation: the share of held-out pairs (by ego vehicle) whose
    preferred reply the model rates above the rejected one, before and after."""
    import torch
    from peft import PeftModel, get_peft_model_state_dict, set_peft_model_state_dict

    from letspi_train.learned.loop import CHECKPOINT_FILE, run_steps  # torch: the train extra

    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    init_manifest = json.loads((Path(init_dir) / MANIFEST_FILE).read_text())
    sft = LoraTrainConfig(**{k: v for k, v in init_manifest["hyperparameters"].items()
                             if k in LoraTrainConfig.__dataclass_fields__})
    train, val = _split_pairs(pairs, config)
    base, tokenizer = load_base(base_gguf)
    model = PeftModel.from_pretrained(base, str(Path(init_dir) / PEFT_DIR), is_trainable=True)
    pad_id = int(tokenizer.pad_token_id if tokenizer.pad_token_id is not None else tokenizer.eos_token_id)

    def encode(p: PreferencePair) -> list[tuple[list[int], list[int]]]:
        return [encode_example(tokenizer, ChatExample(p.messages, reply, "propose", p.scenario_digest))
                for reply in (p.chosen, p.rejected)]

    enc_train = [encode(p) for p in train]
    enc_val = [encode(p) for p in val]
    ref_train, ref_val = _logprobs(model, enc_train, pad_id), _logprobs(model, enc_val, pad_id)
    val_before = _pair_accuracy(ref_val)
    fingerprint = {"dpo": asdict(config), "init_adapter_sha256": init_manifest["adapter"]["sha256"],
                   "pairs_sha256": _pairs_sha(train), "n_train": len(train)}

    def batch_loss(idx: list[int]) -> Any:
        seqs = [s for i in idx for s in enc_train[i]]
        lp = reply_logprobs(model, seqs, pad_id)
        ref = torch.as_tensor(ref_train[idx])
        return dpo_loss(lp[0::2], lp[1::2], ref[:, 0], ref[:, 1], config.beta)

    model.train()
    total = max(1, math.ceil(config.epochs * math.ceil(len(enc_train) / config.batch_size)))
    history = run_steps(
        model, [p for p in model.parameters() if p.requires_grad], n_train=len(enc_train), total_steps=total,
        batch_size=config.batch_size, lr=config.lr, weight_decay=0.0, seed=config.seed, batch_loss=batch_loss,
        lr_factor=lambda step: max(0.1, 1.0 - 0.9 * step / total), clip_norm=1.0,
        trainable_state=lambda: {k: v.detach().clone() for k, v in get_peft_model_state_dict(model).items()},
        load_trainable_state=lambda state: set_peft_model_state_dict(model, state),
        checkpoint_dir=out_dir, checkpoint_every_s=config.checkpoint_every_s, fingerprint=fingerprint,
        progress=progress)
    after = _logprobs(model, enc_val, pad_id)
    verify = [ChatExample(p.messages, p.chosen, "propose", p.scenario_digest) for p in (val or train)[:3]]
    adapter_record, check = _export(model, tokenizer, base_gguf, out_dir, sft, verify)
    manifest: dict[str, Any] = {
        "format": MANIFEST_FORMAT, "model": "smollm2-135m-letspi", "fingerprint": fingerprint,
        "base_model": {"path": provenance_path(base_gguf), "sha256": init_manifest["base_model"]["sha256"]},
        "adapter": adapter_record, "prompt_style": "choice", "hyperparameters": asdict(sft),
        "preference": {**asdict(config), "init": init_manifest["adapter"]["sha256"],
                       "init_manifest_training": init_manifest.get("training", {}).get("command")},
        "data": {**(data_info or {}), "n_pairs_train": len(train), "n_pairs_val": len(val)},
        "training": {**_history_record(history), "val_pair_accuracy_before": val_before,
                     "val_pair_accuracy_after": _pair_accuracy(after),
                     "elapsed_s_this_process": time.perf_counter() - t0, "command": command},
        "export_check": check, "versions": _versions(),
    }
    atomic_write_text(out_dir / MANIFEST_FILE, json.dumps(manifest, indent=2, default=float) + "\n")
    (out_dir / CHECKPOINT_FILE).unlink(missing_ok=True)
    assert (out_dir / ADAPTER_FILE).is_file()
    return manifest


def _history_record(history: StepHistory) -> dict[str, Any]:
    """The manifest's steps, time and losses of a run."""
    losses = history.losses
    return {"steps": history.steps, "train_s": history.train_s, "s_per_step": history.train_s / max(history.steps, 1),
            "first_loss": losses[0] if losses else None,
            "final_loss_mean10": float(np.mean(losses[-10:])) if losses else None,
            "resumed_from_step": history.resumed_from, "loadavg_end": list(os.getloadavg())}


def _split_pairs(pairs: Sequence[PreferencePair], config: DpoConfig) -> tuple[list[PreferencePair],
                                                                              list[PreferencePair]]:
    """(train, validation) by ego vehicle (``split_examples``' rule), the training pairs capped at ``max_pairs``."""
    as_examples = [ChatExample(p.messages, p.chosen, "propose", p.scenario_digest, p.vehicle_key) for p in pairs]
    by_id = {id(e): p for e, p in zip(as_examples, pairs, strict=True)}
    train_e, val_e = split_examples(as_examples, config.val_fraction, config.seed)
    train, val = [by_id[id(e)] for e in train_e], [by_id[id(e)] for e in val_e]
    if config.max_pairs is not None and len(train) > config.max_pairs:
        keep = np.sort(np.random.default_rng(config.seed).permutation(len(train))[: config.max_pairs])
        train = [train[i] for i in keep]
    return train, val


def _logprobs(model: Any, encoded: Sequence[list[tuple[list[int], list[int]]]], pad_id: int) -> np.ndarray:
    """(P, 2) summed reply log-probabilities of each pair's (chosen, rejected), without gradients."""
    import torch

    out = np.zeros((len(encoded), 2))
    model.eval()
    with torch.no_grad():
        for k in range(0, len(encoded), 8):
            seqs = [s for pair in encoded[k : k + 8] for s in pair]
            out[k : k + 8] = reply_logprobs(model, seqs, pad_id).numpy().reshape(-1, 2)
    model.train()
    return out


def _pair_accuracy(logprobs: np.ndarray) -> float:
    """The share of pairs whose preferred reply has the higher log-probability."""
    return float((logprobs[:, 0] > logprobs[:, 1]).mean()) if len(logprobs) else float("nan")


def _pairs_sha(pairs: Sequence[PreferencePair]) -> str:
    h = hashlib.sha256()
    for p in pairs:
        h.update(json.dumps([list(map(dict, p.messages)), p.chosen, p.rejected], sort_keys=True).encode())
    return h.hexdigest()

