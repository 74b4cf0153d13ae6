"""The model's own answers of a verified deciding planner: what it chose before the verification.

Usage: python scripts/model_answers.py PLANNER RESULTS_DIR [RESULTS_DIR ...]

Each RESULTS_DIR is a `letspi evaluate` / `letspi benchmark run` results directory holding per_scenario/PLANNER.
The per-scenario ``reason`` line names the answer (``chose NAME``, or ``kept default`` where the model
answered the defaults or the gate kept them); the verification's replacement follows it
(``verified: ...``). Prints JSON: per answer its share of all windows and of the consulted ones, and how
often the verification replaced it.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.evaluation.harness import load_planner_results

CHOSE = re.compile(r"; chose ([^ ;(]+)")


def own_answer(reason: str) -> str:
    """The answer a reason line records (``default`` where the defaults were kept)."""
    found = CHOSE.search(reason)
    return found.group(1) if found else "default"


def main(planner: str, dirs: list[Path]) -> dict[str, object]:
    frame = pd.concat([load_planner_results(d, planner) for d in dirs], ignore_index=True)
    answers = np.array([own_answer(str(r)) for r in frame["info_reason"]])
    consulted = frame["info_consulted"].to_numpy(bool)
    verified = np.array(["verified:" in str(r) for r in frame["info_reason"]])
    out: dict[str, object] = {"windows": len(frame), "consulted": int(consulted.sum())}
    for name in sorted(set(answers)):
        m = answers == name
        out[name] = {"pct_of_windows": 100 * float(m.mean()),
                     "pct_of_consulted": 100 * float((m & consulted).sum() / max(consulted.sum(), 1)),
                     "replaced_by_verification": int((m & verified).sum())}
    return out


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    print(json.dumps(main(sys.argv[1], [Path(a) for a in sys.argv[2:]]), indent=1))
