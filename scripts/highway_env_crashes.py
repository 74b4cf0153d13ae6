"""What each failed highway-env episode ran into, and whether the planner's own plan already collided.

Usage: python scripts/highway_env_crashes.py RUN_DIR [PLANNER ...]

RUN_DIR is a `letspi highway-env run` / `letspi benchmark run highway-env-...` results directory (all its
planners without PLANNER). Per episode with a collision of the ego, one JSON line: the seed, the time of the
first collision, the vehicle hit (the nearest at that frame) and where it was (ahead or behind, its lateral
offset), the gap and both speeds ``LOOK_BACK_S`` before, whether that vehicle had crashed before (a wreck),
and, for planners that plan, whether the plan made then ran the ego's front past that vehicle's rear within
``LOOK_BACK_S`` (the planner's own plan collided: the tracking did not cause it). Then one summary line per
planner with the episodes of each class:

* ``spawn``: the first collision within ``SPAWN_S`` of the start (the scene starts with a gap no car closes);
* ``side``: the other vehicle was ``SAME_LANE_M`` or more to the side at the collision;
* ``rear-end slow``: into a vehicle ahead in the ego's lane moving at under half the ego's speed;
* ``rear-end``: into another vehicle ahead; ``hit from behind``: the other vehicle was behind.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from letspi_interop.highway_env.store import labels, load_episode, load_episodes

LOOK_BACK_S = 2.0
SPAWN_S = 1.0
SAME_LANE_M = 2.0  # lateral offset below which the other vehicle counts as in the ego's lane


def crash(out: Path, label: str, seed: int) -> dict[str, object] | None:
    """The ego's first collision in one episode (None without one)."""
    tracks, _road, plan_t_s, plans_xy_m = load_episode(out, label, seed)
    e = tracks.ego
    if not tracks.crashed[e].any():
        return None
    k = int(np.argmax(tracks.crashed[e]))
    xy, v = tracks.xy_m, tracks.vxy_mps
    dist = np.hypot(*(xy[:, k] - xy[e, k]).T)
    dist[e] = np.inf
    j = int(np.argmin(dist))
    t_crash = float(tracks.t_s[k])
    b = int(np.searchsorted(tracks.t_s, t_crash - LOOK_BACK_S))
    dx_m, dy_m = (xy[j, b] - xy[e, b]).tolist()
    ahead = bool(xy[j, k, 0] > xy[e, k, 0])
    ego_speed, other_speed = float(v[e, b, 0]), float(v[j, b, 0])
    side = abs(float(xy[j, k, 1] - xy[e, k, 1])) >= SAME_LANE_M
    if t_crash <= SPAWN_S:
        kind = "spawn"
    elif side:
        kind = "side"
    elif not ahead:
        kind = "hit from behind"
    elif abs(dy_m) < SAME_LANE_M and other_speed < 0.5 * ego_speed:
        kind = "rear-end slow"
    else:
        kind = "rear-end"
    row: dict[str, object] = {
        "planner": label, "seed": seed, "t_s": round(t_crash, 2), "kind": kind, "ahead": ahead,
        "gap_m_before": round(dx_m, 1), "lateral_m_before": round(dy_m, 2),
        "ego_speed_mps_before": round(ego_speed, 2), "other_speed_mps_before": round(other_speed, 2),
        "other_wrecked_before": bool(tracks.crashed[j, :k].any()),
    }
    if len(plan_t_s) and ahead:
        r = int(np.searchsorted(plan_t_s, t_crash - LOOK_BACK_S, side="right")) - 1
        if r >= 0:  # the plan's position (F, 2) at 25 Hz from plan_t_s[r] against the other's recorded track
            plan = plans_xy_m[r]
            t_plan = plan_t_s[r] + 0.04 * np.arange(1, len(plan) + 1)
            until = t_plan <= t_crash
            other_x = np.interp(t_plan[until], tracks.t_s, xy[j, :, 0])
            reach = 0.5 * (tracks.length_m[e] + tracks.length_m[j])
            row["plan_t_s"] = round(float(plan_t_s[r]), 2)
            row["plan_collided"] = bool(np.any(plan[until, 0] + reach > other_x))
    return row


def main(out: Path, planners: list[str]) -> None:
    for label in planners or labels(out):
        rows = [crash(out, label, int(s)) for s in load_episodes(out, label)["seed"]]
        crashes = [r for r in rows if r is not None]
        for r in crashes:
            print(json.dumps(r))
        kinds = Counter(str(r["kind"]) for r in crashes)
        planned = sum(bool(r.get("plan_collided")) for r in crashes)
        print(json.dumps({"planner": label, "episodes": len(rows), "collisions": len(crashes), **kinds,
                          "plan_collided": planned}))


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), sys.argv[2:])
