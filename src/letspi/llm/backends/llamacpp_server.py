"""llama-cpp-python's OpenAI-compatible server opened through ``open_llama`` (probe and AMX workaround apply).

    python -m letspi.llm.backends.llamacpp_server --model FILE.gguf --port 8000 [llama_cpp.server options]
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

from letspi.llm.backends.llamacpp_open import import_llama_cpp, runnable_model, without_extra_buffer_types


def server_argv(argv: list[str]) -> list[str]:
    """``argv`` with ``--model``'s file replaced by its runnable form (``runnable_model``)."""
    out = list(argv)
    threads = int(out[out.index("--n_threads") + 1]) if "--n_threads" in out else 2
    if "--model" in out:
        i = out.index("--model") + 1
        out[i] = str(runnable_model(Path(out[i]), n_threads=threads))
    return out


def main() -> None:
    sys.argv = ["llama_cpp.server", *server_argv(sys.argv[1:])]
    llama_mod = import_llama_cpp()
    with without_extra_buffer_types(llama_mod):
        runpy.run_module("llama_cpp.server", run_name="__main__")


if __name__ == "__main__":
    main()
