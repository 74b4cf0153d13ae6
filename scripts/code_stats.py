"""Size and readability figures of the installed package (issue 35's targets), printed as one table.

    python scripts/code_stats.py [--src src/letspi] [--list]

Source lines: every line of every ``.py`` file (split into code, docstring, comment and blank lines). The
companion distributions in ``packages/`` are counted apart (they plug into letspi through entry points; the rule
on long functions covers them too). Docstring lines: lines inside module, class and function
docstrings. Long functions: over 60 lines (``def`` to its last line). ``info_`` literals: string constants
starting with ``info_``, per module. Issue numbers: ``issue N`` / ``#N`` in comments or strings.
"""

from __future__ import annotations

import argparse
import ast
import re
from collections import Counter
from pathlib import Path

ISSUE_RE = re.compile(r"\b[Ii]ssues? #?\d+")


def _docstring_nodes(tree: ast.Module) -> list[ast.Constant]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                out.append(first.value)
    return out


def stats(src: Path) -> dict[str, object]:
    total = doc = comment = blank = 0
    long_modules: list[tuple[str, int]] = []
    long_functions: list[tuple[str, int]] = []
    info_literals: Counter[str] = Counter()
    issues: list[str] = []
    for path in sorted(src.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        rel = str(path.relative_to(src.parent))
        total += len(text.splitlines())
        tree = ast.parse(text)
        doc_lines: set[int] = set()
        for node in _docstring_nodes(tree):
            doc_lines.update(range(node.lineno, (node.end_lineno or node.lineno) + 1))
        doc += len(doc_lines)
        for i, line in enumerate(text.splitlines(), 1):
            if i not in doc_lines:
                comment += line.lstrip().startswith("#")
                blank += not line.strip()
        module_doc = ast.get_docstring(tree, clean=False)
        if module_doc is not None:
            first = tree.body[0]
            n = (first.end_lineno or first.lineno) - first.lineno + 1
            if n > 15:
                long_modules.append((rel, n))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = (node.end_lineno or node.lineno) - node.lineno + 1
                if n > 60:
                    long_functions.append((f"{rel}:{node.name}", n))
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("info_"):
                info_literals[rel] += 1
        for i, line in enumerate(text.splitlines(), 1):
            if ISSUE_RE.search(line):
                issues.append(f"{rel}:{i}: {line.strip()[:100]}")
    return {"total": total, "doc": doc, "comment": comment, "blank": blank, "long_modules": long_modules,
            "long_functions": long_functions, "info_literals": info_literals, "issues": issues}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--src", type=Path, default=Path(__file__).resolve().parents[1] / "src" / "letspi")
    parser.add_argument("--list", action="store_true", help="list the offenders")
    args = parser.parse_args()
    s = stats(args.src)
    total, doc = int(s["total"]), int(s["doc"])  # type: ignore[call-overload]
    comment, blank = int(s["comment"]), int(s["blank"])  # type: ignore[call-overload]
    companions = sorted((args.src.parents[1] / "packages").glob("*/src/*/"))
    side = [stats(c) for c in companions]
    rows = [
        ("source lines", f"{total:,}", "<= 34,000"),
        ("of which code / docstring / comment / blank", f"{total - doc - comment - blank:,} / {doc:,} / {comment:,} / "
         f"{blank:,}", ""),
        *((f"companion {c.name} (packages/)", f"{int(t['total']):,}", "")  # type: ignore[call-overload]
          for c, t in zip(companions, side, strict=True)),
        ("docstring lines", f"{doc:,} ({100 * doc / total:.1f} %)", "<= 12 %"),
        ("module docstrings over 15 lines", str(len(s["long_modules"])), "0"),  # type: ignore[arg-type]
        ("functions over 60 lines (with the companions')",
         str(len(s["long_functions"]) + sum(len(t["long_functions"]) for t in side)), "<= 8"),  # type: ignore[arg-type, misc]
        ("info_ literals (modules)", f"{sum(s['info_literals'].values())} ({len(s['info_literals'])})", "0 outside "  # type: ignore[attr-defined]
         "the declaring modules"),
        ("issue numbers", str(len(s["issues"])), "0"),  # type: ignore[arg-type]
    ]
    print("| figure | now | target |\n|---|---:|---|")
    for row in rows:
        print(f"| {row[0]} | {row[1]} | {row[2]} |")
    if args.list:
        for key in ("long_modules", "long_functions", "issues"):
            print(f"\n{key}:")
            for item in s[key]:  # type: ignore[attr-defined]
                print(f"  {item}")
        print("\ninfo_ literals:")
        for mod, n in s["info_literals"].most_common():  # type: ignore[attr-defined]
            print(f"  {mod}: {n}")


if __name__ == "__main__":
    main()
