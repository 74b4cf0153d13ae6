"""Architecture rules that import-linter cannot express: imports live at module level.

Function-level imports are allowed only for heavy optional dependencies (they may be missing, and
importing them costs seconds or starts native runtimes). Everything else is imported at the top,
so a module's dependencies are visible in one place and import cycles cannot hide.
"""

from __future__ import annotations

import ast
from pathlib import Path

import letspi

HEAVY_OPTIONAL = ("torch", "transformers", "peft", "gguf", "llama_cpp", "libsumo", "traci", "sumolib", "ray")
#: letspi packages whose modules import a heavy optional dependency (torch) at module level
HEAVY_PACKAGES = ("letspi.learned.train", "letspi.finetune")
SRC = Path(letspi.__file__).parent


def _function_level_imports() -> list[str]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for func in ast.walk(tree):
            if not isinstance(func, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(func):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    heavy = name.split(".")[0] in HEAVY_OPTIONAL or name.startswith(HEAVY_PACKAGES)
                    if not heavy:
                        found.append(f"{path.relative_to(SRC.parent)}:{node.lineno} imports {name} in {func.name}()")
    return found


def test_only_heavy_optional_dependencies_are_imported_inside_functions() -> None:
    offenders = _function_level_imports()
    assert not offenders, "function-level imports of light modules:\n" + "\n".join(offenders)
