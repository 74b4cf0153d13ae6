"""PEFT LoRA weights -> a llama.cpp LoRA adapter GGUF, laid out as llama.cpp's ``convert_lora_to_gguf.py`` does.

Metadata: the base's ``general.architecture``, ``general.type`` = ``adapter``, ``adapter.type`` = ``lora``,
``adapter.lora.alpha`` (llama.cpp scales by alpha / rank). Per adapted matrix W (out, in):
``blk.N.<tensor>.weight.lora_a`` = PEFT ``lora_A`` (rank, in) and ``.lora_b`` = ``lora_B`` (out, rank),
row-major (ggml reads the dims reversed, so it computes B A x). ``lora_b`` of q/k gets the rotary row
permutation llama.cpp's converter applies to the base. Embeddings and ``lm_head`` are refused.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

import numpy as np

#: HF Llama module path (inside ``model.layers.N.``) -> GGUF tensor base name (inside ``blk.N.``).
HF_TO_GGUF: Final[dict[str, str]] = {
    "self_attn.q_proj": "attn_q",
    "self_attn.k_proj": "attn_k",
    "self_attn.v_proj": "attn_v",
    "self_attn.o_proj": "attn_output",
    "mlp.gate_proj": "ffn_gate",
    "mlp.up_proj": "ffn_up",
    "mlp.down_proj": "ffn_down",
}
_PEFT_NAME: Final = re.compile(
    r"^(?:base_model\.model\.)?model\.layers\.(\d+)\.(self_attn\.[qkvo]_proj|mlp\.(?:gate|up|down)_proj)"
    r"\.lora_([AB])(?:\.default)?\.weight$"
)


class AdapterExportError(ValueError):
    """A LoRA state dict that cannot be written as a llama.cpp adapter."""


def gguf_lora_name(peft_name: str) -> str:
    """PEFT tensor name -> GGUF adapter tensor name, e.g.
    ``base_model.model.model.layers.3.self_attn.q_proj.lora_A.weight`` -> ``blk.3.attn_q.weight.lora_a``."""
    m = _PEFT_NAME.match(peft_name)
    if m is None:
        raise AdapterExportError(
            f"LoRA tensor {peft_name!r} is not an attention/MLP projection of a Llama layer "
            "(embeddings and lm_head are not adapted)")
    layer, module, ab = m.groups()
    return f"blk.{int(layer)}.{HF_TO_GGUF[module]}.weight.lora_{ab.lower()}"


def permute_rotary_rows(w: np.ndarray, n_head: int) -> np.ndarray:
    """llama.cpp's q/k row permutation (per head, the two rotary halves interleaved) of
    w (n_head * head_dim, cols) -> same shape."""
    rows = w.shape[0]
    if rows % (2 * n_head):
        raise AdapterExportError(f"{rows} rows do not split into {n_head} heads of an even size")
    return w.reshape(n_head, 2, rows // n_head // 2, *w.shape[1:]).swapaxes(1, 2).reshape(w.shape)


def adapter_tensors(state: Mapping[str, Any], *, n_head: int, n_kv_head: int) -> dict[str, np.ndarray]:
    """GGUF adapter tensors (float32, PyTorch layout) of a PEFT LoRA state dict; ``n_head`` / ``n_kv_head``
    permute q / k rows; every ``lora_a`` needs its ``lora_b`` and vice versa."""
    out: dict[str, np.ndarray] = {}
    for name, value in state.items():
        arr = np.asarray(value.detach().cpu().float().numpy() if hasattr(value, "detach") else value,
                         dtype=np.float32)
        if arr.ndim != 2:
            raise AdapterExportError(f"LoRA tensor {name!r} has shape {arr.shape}; expected a matrix")
        gname = gguf_lora_name(name)
        if gname.endswith("lora_b"):
            if ".attn_q." in gname:
                arr = permute_rotary_rows(arr, n_head)
            elif ".attn_k." in gname:
                arr = permute_rotary_rows(arr, n_kv_head)
        out[gname] = np.ascontiguousarray(arr)
    for gname, arr in out.items():
        other = gname[:-1] + ("b" if gname.endswith("a") else "a")
        if other not in out:
            raise AdapterExportError(f"{gname} has no matching {other}")
        a, b = (arr, out[other]) if gname.endswith("a") else (out[other], arr)
        if a.shape[0] != b.shape[1]:
            raise AdapterExportError(f"{gname}: rank of lora_a {a.shape} and lora_b {b.shape} differ")
    return dict(sorted(out.items(), key=lambda kv: _tensor_order(kv[0])))


def _tensor_order(gname: str) -> tuple[int, str]:
    parts = gname.split(".")
    return int(parts[1]), ".".join(parts[2:])


def write_adapter_gguf(path: Path, tensors: Mapping[str, np.ndarray], *, alpha: float, arch: str = "llama",
                       name: str = "letspi LoRA") -> Path:
    """Write ``tensors`` (``adapter_tensors``) as a llama.cpp LoRA adapter GGUF (float32)."""
    import gguf

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    writer = gguf.GGUFWriter(str(tmp), arch=arch)
    writer.add_type(gguf.GGUFType.ADAPTER)
    writer.add_string(gguf.Keys.Adapter.TYPE, "lora")
    writer.add_float32(gguf.Keys.Adapter.LORA_ALPHA, float(alpha))
    writer.add_name(name)
    for tname, arr in tensors.items():
        writer.add_tensor(tname, np.ascontiguousarray(arr, dtype=np.float32))
    writer.write_header_to_file()
    writer.write_kv_data_to_file()
    writer.write_tensors_to_file()
    writer.close()
    tmp.replace(path)
    return path


def read_adapter_gguf(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(metadata of interest, tensors in PyTorch layout) of an adapter GGUF, for checks and tests."""
    import gguf

    reader = gguf.GGUFReader(str(path))
    meta: dict[str, Any] = {}
    for key in ("general.architecture", "general.type", "adapter.type", "adapter.lora.alpha"):
        field = reader.get_field(key)
        if field is not None:
            meta[key] = field.contents()
    tensors = {t.name: np.asarray(t.data).reshape(tuple(int(d) for d in reversed(t.shape))) for t in reader.tensors}
    return meta, tensors
