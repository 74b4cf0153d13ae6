"""Where a deciding planner kept the defaults: does it plan as the reference (``sf``) does, and where not, why?

Usage: python scripts/default_windows.py PLANNER REFERENCE RESULTS_DIR [RESULTS_DIR ...]

Each RESULTS_DIR is a `letspi evaluate` / `letspi benchmark run` results directory of one mode holding
per_scenario/PLANNER and per_scenario/REFERENCE; windows are paired by scenario digest. Among the windows
whose ``info_decision`` is ``default``, prints JSON per group (consulted or not, shielded or not, and the
shield's source: 0 the plan itself, -3 a preset, 1..k a retrieved memory, -1 the fitted parameters, -2 a
grid candidate): the windows, the at-fault contacts and successes of both, and the windows only one of
them has an at-fault contact.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from letspi.analysis.decisions import paired_rows


def main(planner: str, reference: str, dirs: list[Path]) -> dict[str, object]:
    p = paired_rows(dirs, planner, reference)
    a, r = p.planner, p.reference
    default = np.asarray(a["info_decision"] == "default")
    a, r = a[default], r[default]
    groups: dict[str, object] = {}
    keys = (np.where(a["info_consulted"].astype(bool), "consulted", "gate kept")
            + np.where(a["info_shielded"].astype(float) > 0,
                       " / shielded by " + a["info_shield_source"].astype(int).astype(str), " / not shielded"))
    for key in sorted(set(keys)):
        m = keys == key
        af, af_ref = a["collision_at_fault"].to_numpy(bool)[m], r["collision_at_fault"].to_numpy(bool)[m]
        groups[str(key)] = {"windows": int(m.sum()), "at_fault": int(af.sum()), "at_fault_ref": int(af_ref.sum()),
                            "only_planner_at_fault": int((af & ~af_ref).sum()),
                            "only_ref_at_fault": int((af_ref & ~af).sum()),
                            "success": int(a["success"].to_numpy(bool)[m].sum()),
                            "success_ref": int(r["success"].to_numpy(bool)[m].sum())}
    return {"windows_default": int(default.sum()), "at_fault": int(a["collision_at_fault"].sum()),
            "at_fault_ref": int(r["collision_at_fault"].sum()), "groups": groups}


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    print(json.dumps(main(sys.argv[1], sys.argv[2], [Path(a) for a in sys.argv[3:]]), indent=1))
