"""Compare the scene texts of ``letspi/llm/describe.py`` at a git revision with the working tree's.

For a refactoring of the code that describes scenes: every text a prompt takes from a description
(``to_text`` full and brief, ``summary_line``, ``targeted_guidance``, the compact scene) must stay byte
for byte the same. The old module is loaded from ``git show REV:src/letspi/llm/describe.py``; both
describe the same scenes with the same random goals: 3,000 degenerate scenes
(``benchmarks/degenerate.py``) and, if given, every scenario of a scenario file.

    python scripts/compare_descriptions.py main [SCENARIOS.arrow]

Prints ``N of M descriptions identical`` and the first differences; exit code 1 when any differs.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path
from types import ModuleType

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository's benchmarks/

from benchmarks.degenerate import degenerate_scenarios
from letspi.llm import describe as new
from letspi.llm.compact import compact_scene_text
from letspi.scenario.store import load_scenarios
from letspi.scenario.types import ScenarioBatch


def old_module(rev: str, folder: Path) -> ModuleType:
    source = subprocess.run(["git", "show", f"{rev}:src/letspi/llm/describe.py"], capture_output=True, text=True,
                            check=True).stdout
    path = folder / "describe_old.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("describe_old", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["describe_old"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def texts(module: ModuleType, batch: ScenarioBatch, index: int, goal: tuple[float, float]) -> tuple[str, ...]:
    try:
        d = module.describe_scenario(batch, goal, index=index)
    except ValueError as exc:  # a scene both must refuse alike
        return ("error", str(exc))
    return (d.to_text(detail="full"), d.to_text(detail="brief"), d.summary_line(),
            "\n".join(module.targeted_guidance(d)), compact_scene_text(d))


def main(rev: str, scenarios: str | None = None) -> int:
    batches = [degenerate_scenarios(3000, seed=7)]
    if scenarios:
        batches.append(load_scenarios(Path(scenarios)))
    rng = np.random.default_rng(0)
    n = same = 0
    with tempfile.TemporaryDirectory() as tmp:
        old = old_module(rev, Path(tmp))
        for batch in batches:
            for i in range(len(batch)):
                goal = (float(rng.uniform(0, 200)), float(rng.uniform(-8, 8)))
                a, b = texts(old, batch, i, goal), texts(new, batch, i, goal)
                n += 1
                same += a == b
                if a != b and n - same <= 3:
                    print(f"differs: {batch.scenario_id[i]}\n--- {rev}\n{a}\n--- working tree\n{b}")
    print(f"{same} of {n} descriptions identical (full, brief, summary, guidance, compact scene)")
    return 0 if same == n else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
