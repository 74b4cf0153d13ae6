"""What a GGUF model file holds (its tensor types decide the llama.cpp kernels), read from the header only."""

from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path
from typing import BinaryIO, Final

MAGIC: Final = b"GGUF"

#: ggml tensor type ids (ggml.h ``enum ggml_type``) -> names
GGML_TYPES: Final[dict[int, str]] = {
    0: "F32", 1: "F16", 2: "Q4_0", 3: "Q4_1", 6: "Q5_0", 7: "Q5_1", 8: "Q8_0", 9: "Q8_1", 10: "Q2_K",
    11: "Q3_K", 12: "Q4_K", 13: "Q5_K", 14: "Q6_K", 15: "Q8_K", 16: "IQ2_XXS", 17: "IQ2_XS", 18: "IQ3_XXS",
    19: "IQ1_S", 20: "IQ4_NL", 21: "IQ3_S", 22: "IQ2_S", 23: "IQ4_XS", 24: "I8", 25: "I16", 26: "I32",
    27: "I64", 28: "F64", 29: "IQ1_M", 30: "BF16", 34: "TQ1_0", 35: "TQ2_0", 39: "MXFP4",
}
#: formats whose matrix products run without quantized kernels (llama.cpp's AMX path handles none of them)
FLOAT_TYPES: Final = frozenset({"F32", "F16", "BF16", "F64"})

# GGUF metadata value types: fixed-size scalars by id (struct format), 8 = string, 9 = array
_SCALARS: Final[dict[int, str]] = {0: "B", 1: "b", 2: "H", 3: "h", 4: "I", 5: "i", 6: "f", 7: "?", 10: "Q", 11: "q",
                                   12: "d"}


class GGUFHeaderError(ValueError):
    """Not a readable GGUF file (the message names the file and what is wrong)."""


def _read(fh: BinaryIO, fmt: str) -> int:
    size = struct.calcsize("<" + fmt)
    raw = fh.read(size)
    if len(raw) != size:
        raise EOFError
    return int(struct.unpack("<" + fmt, raw)[0])


def _skip_string(fh: BinaryIO) -> None:
    fh.seek(_read(fh, "Q"), 1)


def _skip_value(fh: BinaryIO, value_type: int) -> None:
    if value_type in _SCALARS:
        fh.seek(struct.calcsize("<" + _SCALARS[value_type]), 1)
    elif value_type == 8:
        _skip_string(fh)
    elif value_type == 9:
        item_type, n = _read(fh, "I"), _read(fh, "Q")
        if item_type in _SCALARS:
            fh.seek(n * struct.calcsize("<" + _SCALARS[item_type]), 1)
        else:
            for _ in range(n):
                _skip_value(fh, item_type)
    else:
        raise GGUFHeaderError(f"unknown metadata value type {value_type}")


def tensor_types(path: Path) -> Counter[str]:
    """How many tensors of each ggml type ``path`` holds, e.g. ``{"Q4_1": 210, "F32": 61, "Q8_0": 1}``."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            if fh.read(4) != MAGIC:
                raise GGUFHeaderError(f"{path}: not a GGUF file (no GGUF magic at its start)")
            version = _read(fh, "I")
            if version < 2:
                raise GGUFHeaderError(f"{path}: GGUF version {version} is too old (2 or newer is read)")
            n_tensors, n_kv = _read(fh, "Q"), _read(fh, "Q")
            for _ in range(n_kv):
                _skip_string(fh)
                _skip_value(fh, _read(fh, "I"))
            counts: Counter[str] = Counter()
            for _ in range(n_tensors):
                _skip_string(fh)
                fh.seek(8 * _read(fh, "I"), 1)  # the dimensions
                type_id = _read(fh, "I")
                fh.seek(8, 1)  # the data offset
                counts[GGML_TYPES.get(type_id, f"type{type_id}")] += 1
    except EOFError:
        raise GGUFHeaderError(f"{path}: truncated GGUF header") from None
    return counts


def model_format(path: Path) -> str:
    """The tensor types beyond F32 that ``path`` holds, sorted and joined by ``+`` (``Q4_1+Q8_0``; ``F32``)."""
    types = sorted(t for t in tensor_types(path) if t != "F32")
    return "+".join(types) or "F32"


def is_float_format(fmt: str) -> bool:
    """Whether a ``model_format`` holds only float tensors (no quantized kernels run)."""
    return all(t in FLOAT_TYPES for t in fmt.split("+"))
