"""LoRA fine-tuning of the embedded SmolLM2-135M-Instruct on physics-verified labels (the ``train`` extra).

The base is the packaged GGUF loaded by transformers (dequantized; tokenizer and chat template from the same
file), so the model fine-tuned is the one llama.cpp runs. LoRA adapts the attention and MLP projections
(``TARGET_MODULES``), optionally of the last ``layers`` only; embeddings and ``lm_head`` never, so llama.cpp
applies the adapter to the unchanged base. Loss: cross-entropy on the reply tokens only. Output: ``adapter.gguf``,
``peft/`` and ``manifest.json``. Deterministic for a seed and thread count on CPU.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

import numpy as np

from letspi.assembly.resolve import file_sha256
from letspi.fsutil import atomic_write_text, provenance_path
from letspi.llm.backends.llamacpp_open import open_llama
from letspi_train.finetune.data import ChatExample, split_examples
from letspi_train.finetune.export import adapter_tensors, write_adapter_gguf

if TYPE_CHECKING:  # torch is the train extra's; the module imports without it
    from letspi_train.learned.loop import StepHistory

ADAPTER_FILE: Final = "adapter.gguf"
MANIFEST_FILE: Final = "manifest.json"
PEFT_DIR: Final = "peft"
MANIFEST_FORMAT: Final = "letspi-llm-adapter/1"
#: The Llama projections that get a LoRA update (no embeddings, no lm_head).
TARGET_MODULES: Final[tuple[str, ...]] = ("q_proj", "k_proj", "v_proj", "o_proj", "gate_proj", "up_proj", "down_proj")
END_OF_TURN: Final = "<|im_end|>"
IGNORE_INDEX: Final = -100
#: bf16 autocast is used only when the first batch's loss stays within this relative distance of float32's
BF16_LOSS_TOLERANCE: Final = 0.02
#: ... or within this many nats: a continued run starts near zero loss, where 2 % is noise (0.0048 vs 0.0049)
BF16_LOSS_ABS_TOLERANCE_NATS: Final = 0.01


@dataclass(frozen=True)
class LoraTrainConfig:
    """Hyperparameters of ``train_lora`` (all recorded in the manifest)."""

    epochs: float = 1.0
    lr: float = 3e-4
    rank: int = 8
    alpha: int = 16
    dropout: float = 0.05
    batch_size: int = 8
    warmup_steps: int = 10
    weight_decay: float = 0.0
    seed: int = 0
    max_steps: int | None = None
    val_fraction: float = 0.1
    max_val: int = 48  # validation examples evaluated (teacher-forced loss before and after)
    threads: int = 2
    layers: int | None = None  # adapt only the last N transformer layers (None: all)
    precision: Literal["auto", "fp32", "bf16"] = "auto"  # bf16 autocast of the forward pass (``choose_precision``)
    checkpoint_every_s: float = 300.0  # resumable checkpoint period (training seconds)
    balance: float = 0.0  # repeat training examples towards rare replies (``rebalance``; 0: as labelled)

    def __post_init__(self) -> None:
        if self.rank < 1 or self.batch_size < 1 or self.lr <= 0 or self.epochs <= 0:
            raise ValueError("--rank, --batch-size, --lr and --epochs must be positive")
        if self.max_steps is not None and self.max_steps < 1:
            raise ValueError("--max-steps must be >= 1")
        if self.layers is not None and self.layers < 1:
            raise ValueError("--layers must be >= 1")
        if self.precision not in ("auto", "fp32", "bf16"):
            raise ValueError(f"--precision must be auto, fp32 or bf16, got {self.precision!r}")
        if self.checkpoint_every_s <= 0:
            raise ValueError("--checkpoint-every-s must be positive")
        if not 0.0 <= self.balance <= 1.0:
            raise ValueError("--balance must be in [0, 1]")


def rebalance(examples: Sequence[ChatExample], power: float, cap: int = 8) -> list[ChatExample]:
    """Each example repeated ``round((n_top / n_reply) ** power)`` times (at least once, at most ``cap``), where
    ``n_reply`` counts the examples with its reply and ``n_top`` those of the commonest reply: ``power`` 1
    evens the replies out, 0 keeps the labels' shares. In order (each example's copies together)."""
    if power <= 0 or not examples:
        return list(examples)
    counts: dict[str, int] = {}
    for e in examples:
        counts[e.reply] = counts.get(e.reply, 0) + 1
    top = max(counts.values())
    out: list[ChatExample] = []
    for e in examples:
        out += [e] * min(cap, max(1, round((top / counts[e.reply]) ** power)))
    return out


def load_base(gguf_path: Path) -> tuple[Any, Any]:
    """(float32 ``LlamaForCausalLM``, tokenizer) from a GGUF file (transformers dequantizes it)."""
    from transformers import AutoModelForCausalLM, AutoTokenizer

    directory, name = str(Path(gguf_path).parent), Path(gguf_path).name
    tokenizer = AutoTokenizer.from_pretrained(directory, gguf_file=name)
    model = AutoModelForCausalLM.from_pretrained(directory, gguf_file=name)
    model.config.use_cache = False
    return model, tokenizer


def prompt_text(tokenizer: Any, messages: Sequence[Any]) -> str:
    """The chat-template text up to the assistant turn (what llama.cpp's chat completion feeds the model)."""
    return str(tokenizer.apply_chat_template([dict(m) for m in messages], tokenize=False, add_generation_prompt=True))


def encode_example(tokenizer: Any, example: ChatExample) -> tuple[list[int], list[int]]:
    """(input ids, labels): prompt then reply + end of turn, labels masking the prompt (``IGNORE_INDEX``);
    tokenized apart, as at inference."""
    prompt_ids = tokenizer(prompt_text(tokenizer, example.messages), add_special_tokens=False)["input_ids"]
    reply_ids = tokenizer(example.reply + END_OF_TURN, add_special_tokens=False)["input_ids"]
    return list(prompt_ids) + list(reply_ids), [IGNORE_INDEX] * len(prompt_ids) + list(reply_ids)


def _collate(batch: Sequence[tuple[list[int], list[int]]], pad_id: int) -> tuple[Any, Any, Any, int]:
    """Left-padded (ids, labels, attention mask), each (B, T), and the trailing positions the loss needs (the
    reply tail + 1): only those go through the output layer (RoPE is relative, so padding changes nothing)."""
    import torch

    n = max(len(ids) for ids, _ in batch)
    ids = torch.full((len(batch), n), pad_id, dtype=torch.long)
    labels = torch.full((len(batch), n), IGNORE_INDEX, dtype=torch.long)
    mask = torch.zeros((len(batch), n), dtype=torch.long)
    tail = 1
    for i, (x, y) in enumerate(batch):
        ids[i, n - len(x):] = torch.tensor(x)
        labels[i, n - len(y):] = torch.tensor(y)
        mask[i, n - len(x):] = 1
        tail = max(tail, 1 + sum(1 for t in y if t != IGNORE_INDEX))
    return ids, labels, mask, min(tail, n)


def _reply_loss(model: Any, ids: Any, labels: Any, mask: Any, tail: int, reduction: str = "mean") -> Any:
    """Cross-entropy of the reply tokens; logits only over the last ``tail`` positions."""
    import torch

    logits = model(input_ids=ids, attention_mask=mask, logits_to_keep=tail).logits[:, :-1]
    target = labels[:, ids.shape[1] - tail + 1:]
    return torch.nn.functional.cross_entropy(logits.reshape(-1, logits.shape[-1]).float(), target.reshape(-1),
                                             ignore_index=IGNORE_INDEX, reduction=reduction)


def _mean_loss(model: Any, encoded: Sequence[tuple[list[int], list[int]]], pad_id: int, batch_size: int) -> float:
    """Token-weighted mean reply cross-entropy (nats/token)."""
    import torch

    if not encoded:
        return float("nan")
    total, count = 0.0, 0
    model.eval()
    with torch.no_grad():
        for k in range(0, len(encoded), batch_size):
            ids, labels, mask, tail = _collate(encoded[k : k + batch_size], pad_id)
            total += float(_reply_loss(model, ids, labels, mask, tail, reduction="sum"))
            count += int((labels != IGNORE_INDEX).sum())
    return total / max(count, 1)


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("torch", "transformers", "peft", "gguf", "llama-cpp-python"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "absent"
    return out


def greedy_torch(model: Any, tokenizer: Any, messages: Sequence[Any], max_new_tokens: int) -> list[int]:
    """Greedy continuation token ids (no grammar) of the prompt, with torch (KV cache via ``generate``)."""
    import torch

    ids = tokenizer(prompt_text(tokenizer, messages), add_special_tokens=False, return_tensors="pt")["input_ids"]
    eos = int(tokenizer.convert_tokens_to_ids(END_OF_TURN))
    model.eval()
    with torch.no_grad():
        out = model.generate(input_ids=ids, attention_mask=torch.ones_like(ids), max_new_tokens=max_new_tokens,
                             do_sample=False, eos_token_id=eos, pad_token_id=eos, use_cache=True)
    return [int(t) for t in out[0, ids.shape[1]:]]


def greedy_llamacpp(llm: Any, prompt_ids: Sequence[int], max_new_tokens: int, eos: int) -> list[int]:
    """Greedy continuation token ids of ``prompt_ids`` with a loaded ``llama_cpp.Llama``."""
    llm.reset()
    out: list[int] = []
    for tok in llm.generate(list(prompt_ids), top_k=1, top_p=1.0, min_p=0.0, temp=0.0, repeat_penalty=1.0,
                            reset=True):
        out.append(int(tok))
        if tok == eos or len(out) >= max_new_tokens:
            break
    return out


def verify_export(model: Any, tokenizer: Any, base_gguf: Path, adapter_gguf: Path,
                  examples: Sequence[ChatExample], max_new_tokens: int = 64) -> dict[str, Any]:
    """Greedy outputs of torch+peft and llama.cpp+adapter on ``examples``' prompts: per prompt whether the
    tokens agree, their common prefix, and whether both tokenizers give the same prompt ids."""
    # the production settings (flash attention: batched prompt evaluation equals token by token, see
    # letspi.llm.backends.llamacpp), so the check covers the path planners use
    llm = open_llama(Path(base_gguf), n_ctx=1024, n_threads=2, lora_path=Path(adapter_gguf))
    eos = int(tokenizer.convert_tokens_to_ids(END_OF_TURN))
    rows = []
    try:
        for ex in examples:
            text = prompt_text(tokenizer, ex.messages)
            hf_ids = tokenizer(text, add_special_tokens=False)["input_ids"]
            cpp_ids = llm.tokenize(text.encode("utf-8"), add_bos=False, special=True)
            a = greedy_torch(model, tokenizer, ex.messages, max_new_tokens)
            b = greedy_llamacpp(llm, hf_ids, max_new_tokens, eos)
            common = next((k for k, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))
            rows.append({"same_prompt_tokens": list(hf_ids) == list(cpp_ids), "agree": a == b,
                         "common_prefix": common, "n_torch": len(a), "n_llamacpp": len(b),
                         "torch": tokenizer.decode(a), "llamacpp": tokenizer.decode(b)})
    finally:
        llm.close()
    return {"n": len(rows), "agree": sum(r["agree"] for r in rows), "prompts": rows}


def cpu_supports_bf16() -> bool:
    """Whether the CPU has native bfloat16 arithmetic (AVX512_BF16 or AMX-BF16), from /proc/cpuinfo."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            flags = next((line for line in fh if line.startswith("flags")), "")
    except OSError:
        return False
    return " avx512_bf16" in flags or " amx_bf16" in flags


def choose_precision(config: LoraTrainConfig, model: Any, first: tuple[Any, Any, Any, int]) -> dict[str, Any]:
    """``fp32`` or ``bf16`` autocast and the evidence: ``auto`` takes bf16 on a CPU with native bf16 when the
    first batch's loss agrees with float32's (``bf16_loss_agrees``)."""
    import torch

    if config.precision == "fp32" or (config.precision == "auto" and not cpu_supports_bf16()):
        return {"precision": "fp32", "reason": "requested" if config.precision == "fp32" else "no native bf16"}
    ids, labels, mask, tail = first
    model.eval()
    with torch.no_grad():
        fp32 = float(_reply_loss(model, ids, labels, mask, tail))
        with torch.autocast("cpu", dtype=torch.bfloat16):
            bf16 = float(_reply_loss(model, ids, labels, mask, tail))
    rel = abs(bf16 - fp32) / max(abs(fp32), 1e-9)
    chosen = "bf16" if config.precision == "bf16" or bf16_loss_agrees(fp32, bf16) else "fp32"
    return {"precision": chosen, "first_batch_loss_fp32": fp32, "first_batch_loss_bf16": bf16,
            "relative_difference": rel, "tolerance": BF16_LOSS_TOLERANCE,
            "abs_tolerance_nats": BF16_LOSS_ABS_TOLERANCE_NATS}


def bf16_loss_agrees(fp32_loss: float, bf16_loss: float) -> bool:
    """Whether a bf16-autocast loss is close enough to float32's to train in bf16 (relative or absolute)."""
    diff = abs(bf16_loss - fp32_loss)
    return diff <= BF16_LOSS_TOLERANCE * abs(fp32_loss) or diff <= BF16_LOSS_ABS_TOLERANCE_NATS


def run_fingerprint(config: LoraTrainConfig, base_sha256: str, train: Sequence[ChatExample]) -> dict[str, Any]:
    """What identifies a training run for its checkpoint (not threads or checkpoint period: speed only)."""
    h = hashlib.sha256()
    for e in train:
        h.update(json.dumps([list(map(dict, e.messages)), e.reply], sort_keys=True).encode())
    hyper = {k: v for k, v in asdict(config).items() if k not in ("threads", "checkpoint_every_s", "max_val")}
    return {"hyperparameters": hyper, "base_sha256": base_sha256, "train_examples_sha256": h.hexdigest(),
            "n_train": len(train)}


def train_lora(
    examples: Sequence[ChatExample],
    config: LoraTrainConfig,
    base_gguf: Path,
    out_dir: Path,
    *,
    data_info: dict[str, Any] | None = None,
    progress: Callable[[int, int, float], None] | None = None,
    verify: int = 3,
    command: str = "",
    init_dir: Path | None = None,
    train_only: Sequence[ChatExample] = (),
) -> dict[str, Any]:
    """Fine-tune, export ``adapter.gguf`` and write ``manifest.json`` into ``out_dir``; returns the manifest.
    Resumable from ``checkpoint.pt`` (written every ``checkpoint_every_s``); a finished run with this
    fingerprint returns its manifest at once. ``progress(step, total_steps, loss)`` after every step;
    ``verify``: validation (else training) prompts compared by ``verify_export``; ``init_dir``: continue from
    that run's adapter (``check_init`` says what must match); ``train_only``: examples added to the training side
    after the split of ``examples`` (so the validation split stays that of ``examples`` alone)."""
    import torch
    from peft import get_peft_model_state_dict, set_peft_model_state_dict

    from letspi_train.learned.loop import CHECKPOINT_FILE, run_steps  # torch: the train extra

    t_start = time.perf_counter()  # steps: split and fingerprint, encode, LoRA model, run_steps, export
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)

    train, val, val_eval = training_split(examples, config, train_only)
    base_sha = file_sha256(Path(base_gguf))
    fingerprint = run_fingerprint(config, base_sha, train)
    init_manifest = check_init(Path(init_dir), config, base_sha) if init_dir is not None else None
    if init_manifest is not None:
        fingerprint["init_adapter_sha256"] = init_manifest["adapter"]["sha256"]
    done = _finished_manifest(out_dir, fingerprint)
    if done is not None:
        return done
    base, tokenizer = load_base(base_gguf)
    pad_id = int(tokenizer.pad_token_id if tokenizer.pad_token_id is not None else tokenizer.eos_token_id)
    enc_train = [encode_example(tokenizer, e) for e in train]
    enc_val = [encode_example(tokenizer, e) for e in val_eval]
    load_s = time.perf_counter() - t_start

    if init_dir is None:
        model = lora_model(base, config)
    else:
        from peft import PeftModel

        model = PeftModel.from_pretrained(base, str(Path(init_dir) / PEFT_DIR), is_trainable=True)
    n_trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    precision = choose_precision(config, model, _collate(enc_train[: config.batch_size], pad_id))
    val_before = _mean_loss(model, enc_val, pad_id, config.batch_size)

    steps_per_epoch = math.ceil(len(enc_train) / config.batch_size)
    total = max(1, math.ceil(config.epochs * steps_per_epoch))
    if config.max_steps is not None:
        total = min(total, config.max_steps)
    batch_loss = _batch_loss(model, enc_train, pad_id, autocast=precision["precision"] == "bf16")
    history = run_steps(
        model, [p for p in model.parameters() if p.requires_grad], n_train=len(enc_train), total_steps=total,
        batch_size=config.batch_size, lr=config.lr, weight_decay=config.weight_decay, seed=config.seed,
        batch_loss=batch_loss, lr_factor=lr_schedule(config, total), clip_norm=1.0,
        trainable_state=lambda: {k: v.detach().clone() for k, v in get_peft_model_state_dict(model).items()},
        load_trainable_state=lambda state: set_peft_model_state_dict(model, state),
        checkpoint_dir=out_dir, checkpoint_every_s=config.checkpoint_every_s, fingerprint=fingerprint,
        progress=progress)
    val_after = _mean_loss(model, enc_val, pad_id, config.batch_size)

    adapter_record, check = _export(model, tokenizer, base_gguf, out_dir, config, (val_eval or train)[:verify])
    manifest: dict[str, Any] = {
        "format": MANIFEST_FORMAT,
        "model": "smollm2-135m-letspi",
        "fingerprint": fingerprint,
        "base_model": {"path": provenance_path(base_gguf), "sha256": base_sha},
        "adapter": {**adapter_record, "trainable_parameters": int(n_trainable)},
        "prompt_style": (data_info or {}).get("prompt_style", "compact"),
        "hyperparameters": asdict(config),
        "data": {**(data_info or {}), **_data_record(config, train, val, val_eval, enc_train, len(train_only))},
        "training": {**_training_record(config, history, steps_per_epoch, len(enc_train)),
                     "val_loss_before": val_before, "val_loss_after": val_after, **precision,
                     "load_s": load_s, "elapsed_s_this_process": time.perf_counter() - t_start, "command": command},
        "export_check": check,
        "versions": _versions(),
    }
    if init_manifest is not None:
        manifest["init"] = {"adapter_sha256": init_manifest["adapter"]["sha256"],
                            "command": init_manifest.get("training", {}).get("command")}
    atomic_write_text(out_dir / MANIFEST_FILE, json.dumps(manifest, indent=2, default=float) + "\n")
    (out_dir / CHECKPOINT_FILE).unlink(missing_ok=True)  # the adapter and manifest now say it all
    return manifest


#: what a continued run must share with the run it starts from (the LoRA shape, and the split, so that its
#: validation examples stay unseen)
INIT_MUST_MATCH = ("rank", "alpha", "dropout", "layers", "seed", "val_fraction")


def check_init(init_dir: Path, config: LoraTrainConfig, base_sha256: str) -> dict[str, Any]:
    """The manifest of the run in ``init_dir``, after checking that ``config`` may continue it."""
    path = init_dir / MANIFEST_FILE
    if not path.is_file() or not (init_dir / PEFT_DIR).is_dir():
        raise ValueError(f"--init {init_dir}: no finished `letspi train llm` run there ({MANIFEST_FILE}, {PEFT_DIR}/)")
    manifest = json.loads(path.read_text())
    if manifest.get("base_model", {}).get("sha256") != base_sha256:
        raise ValueError(f"--init {init_dir}: trained on another base model")
    hyper = manifest.get("hyperparameters", {})
    for name in INIT_MUST_MATCH:
        if hyper.get(name) != getattr(config, name):
            raise ValueError(f"--init {init_dir}: its --{name.replace('_', '-')} is {hyper.get(name)!r}, "
                             f"this run's {getattr(config, name)!r}; a continued run must keep it")
    return dict(manifest)


def training_split(examples: Sequence[ChatExample], config: LoraTrainConfig, train_only: Sequence[ChatExample] = (),
                   ) -> tuple[list[ChatExample], list[ChatExample], list[ChatExample]]:
    """(train, validation, the ``max_val`` validation examples scored before and after training); ``train_only``
    joins the training side, and may not share an ego vehicle with the validation side."""
    train, val = split_examples(examples, config.val_fraction, config.seed)
    val_vehicles = {e.vehicle_key for e in val if e.vehicle_key}
    shared = sorted({e.vehicle_key for e in train_only if e.vehicle_key in val_vehicles})
    if shared:
        raise ValueError(f"--train-only: {len(shared)} ego vehicles are also on the validation side "
                         f"(e.g. {shared[0]}); pass those labels with --data")
    train = train + list(train_only)
    if not train:
        raise ValueError("no training examples (all in the validation split?)")
    train = rebalance(train, config.balance)  # the validation split keeps the labels' shares
    rng = np.random.default_rng(config.seed)
    val_eval = [val[i] for i in np.sort(rng.permutation(len(val))[: config.max_val])] if val else []
    return train, val, val_eval


def _export(model: Any, tokenizer: Any, base_gguf: Path, out_dir: Path, config: LoraTrainConfig,
            verify_examples: Sequence[ChatExample]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Write the PEFT and llama.cpp adapters and run ``verify_export``: (the adapter record, the check or None)."""
    from peft import get_peft_model_state_dict

    model.save_pretrained(str(out_dir / PEFT_DIR))
    cfg = model.base_model.model.config
    tensors = adapter_tensors(get_peft_model_state_dict(model), n_head=int(cfg.num_attention_heads),
                              n_kv_head=int(cfg.num_key_value_heads))
    adapter = write_adapter_gguf(out_dir / ADAPTER_FILE, tensors, alpha=config.alpha)
    check = verify_export(model, tokenizer, base_gguf, adapter, verify_examples) if verify_examples else None
    record = {"file": ADAPTER_FILE, "sha256": file_sha256(adapter), "bytes": adapter.stat().st_size,
              "n_tensors": len(tensors), "target_modules": list(TARGET_MODULES)}
    return record, check


def lora_model(base: Any, config: LoraTrainConfig) -> Any:
    """``base`` with LoRA on ``TARGET_MODULES`` of every layer, or of the last ``config.layers``."""
    from peft import LoraConfig, get_peft_model

    n_layers = int(base.config.num_hidden_layers)
    layers = list(range(n_layers - min(config.layers, n_layers), n_layers)) if config.layers else None
    lora = LoraConfig(r=config.rank, lora_alpha=config.alpha, lora_dropout=config.dropout,
                      target_modules=list(TARGET_MODULES), layers_to_transform=layers, bias="none",
                      task_type="CAUSAL_LM")
    return get_peft_model(base, lora)


def lr_schedule(config: LoraTrainConfig, total: int) -> Callable[[int], float]:
    """Learning-rate factor per step: linear warm-up over ``warmup_steps``, then linear decay to 10 %."""

    def factor(step: int) -> float:
        if step < config.warmup_steps:
            return (step + 1) / config.warmup_steps
        frac = (step - config.warmup_steps) / max(1, total - config.warmup_steps)
        return max(0.1, 1.0 - 0.9 * frac)

    return factor


def _batch_loss(model: Any, encoded: Sequence[tuple[list[int], list[int]]], pad_id: int,
                *, autocast: bool) -> Callable[[list[int]], Any]:
    """The reply loss of the training examples at some indices (forward under bf16 autocast if asked)."""
    import torch

    def loss(idx: list[int]) -> Any:
        ids, labels, mask, tail = _collate([encoded[i] for i in idx], pad_id)
        if autocast:
            with torch.autocast("cpu", dtype=torch.bfloat16):
                return _reply_loss(model, ids, labels, mask, tail)
        return _reply_loss(model, ids, labels, mask, tail)

    return loss


def _data_record(config: LoraTrainConfig, train: Sequence[ChatExample], val: Sequence[ChatExample],
                 val_eval: Sequence[ChatExample], enc_train: Sequence[tuple[list[int], list[int]]],
                 n_train_only: int = 0) -> dict[str, Any]:
    """The manifest's data section: split, sizes, kinds and token counts."""
    return {"n_train": len(train), "n_val": len(val), "n_val_evaluated": len(val_eval), "n_train_only": n_train_only,
            "split": f"by ego vehicle, {100 * config.val_fraction:.0f} % validation, seed {config.seed}",
            "train_vehicles": len({e.vehicle_key for e in train}),
            "val_vehicles": len({e.vehicle_key for e in val}),
            "train_kinds": {k: sum(e.kind == k for e in train) for k in sorted({e.kind for e in train})},
            "train_reply_tokens": int(sum(sum(t != IGNORE_INDEX for t in y) for _, y in enc_train)),
            "mean_prompt_tokens": float(np.mean([sum(t == IGNORE_INDEX for t in y) for _, y in enc_train]))}


def _training_record(config: LoraTrainConfig, history: StepHistory, steps_per_epoch: int,
                     n_train: int) -> dict[str, Any]:
    """The manifest's training section: steps, losses, timing, resume and the machine's load."""
    losses, total = history.losses, history.steps
    epoch_len = max(1, steps_per_epoch)
    return {"steps": total, "examples_seen": total * config.batch_size,
            "epochs_done": total * config.batch_size / n_train,
            "first_loss": losses[0], "final_loss_mean10": float(np.mean(losses[-min(len(losses), 10):])),
            "epoch_mean_loss": [float(np.mean(losses[k:k + epoch_len])) for k in range(0, len(losses), epoch_len)],
            "resumed_from_step": history.resumed_from, "checkpoints_written": history.checkpoints_written,
            "train_s": history.train_s, "s_per_step": history.train_s / max(total, 1),
            "threads": config.threads, "cpu": platform.processor() or platform.machine(),
            "loadavg_end": list(os.getloadavg()), "created": datetime.now(UTC).isoformat(timespec="seconds")}


def _finished_manifest(out_dir: Path, fingerprint: dict[str, Any]) -> dict[str, Any] | None:
    """The manifest of a finished run with this fingerprint in ``out_dir`` (a rerun is then a no-op)."""
    path = out_dir / MANIFEST_FILE
    if not path.is_file() or not (out_dir / ADAPTER_FILE).is_file():
        return None
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if manifest.get("fingerprint") != json.loads(json.dumps(fingerprint)):
        return None
    return dict(manifest)
