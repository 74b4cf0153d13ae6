"""Where a deciding planner's success (SR) differs from the reference's, per decision, pooled over results.

Usage: python scripts/decision_success.py PLANNER REFERENCE RESULTS_DIR [RESULTS_DIR ...]

Each RESULTS_DIR is a `letspi evaluate` / `letspi benchmark run` results directory of one mode (it holds
per_scenario/PLANNER and per_scenario/REFERENCE). Windows are paired by scenario digest. Prints JSON: the
windows where only the reference succeeds ("lost") and only the planner ("gained"), why the lost ones
failed (collision, recorded endpoint not reached), and per decision (``info_decision``) the windows, the
SR of both and their at-fault contacts.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from letspi.analysis.decisions import paired_rows

COLUMNS = ["collision", "collision_at_fault", "success", "reference_reached"]


def main(planner: str, reference: str, dirs: list[Path]) -> dict[str, object]:
    p = paired_rows(dirs, planner, reference)
    m = p.planner[[*COLUMNS, "info_decision"]].join(p.reference[COLUMNS].add_suffix("_ref"))
    lost = m[m["success_ref"] & ~m["success"]]
    gained = m[~m["success_ref"] & m["success"]]
    per_decision = {}
    for decision, g in m.groupby("info_decision"):
        per_decision[str(decision)] = {
            "windows": len(g), "sr_pct": round(100 * g["success"].mean(), 1),
            "sr_ref_pct": round(100 * g["success_ref"].mean(), 1),
            "at_fault": int(g["collision_at_fault"].sum()), "at_fault_ref": int(g["collision_at_fault_ref"].sum())}
    return {"windows": len(m), "lost": len(lost), "gained": len(gained),
            "lost_collision": int(lost["collision"].sum()),
            "lost_reference_not_reached": int((~lost["reference_reached"]).sum()),
            "lost_by_decision": lost["info_decision"].value_counts().to_dict(),
            "gained_by_decision": gained["info_decision"].value_counts().to_dict(),
            "per_decision": per_decision}


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    print(json.dumps(main(sys.argv[1], sys.argv[2], [Path(a) for a in sys.argv[3:]]), indent=1))
