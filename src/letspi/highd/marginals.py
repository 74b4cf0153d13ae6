"""Traffic marginals of HighD recordings beside what the highD authors published (``letspi data info --compare-highd``).

Measured: vehicles, truck share, recorded minutes; share of lane-changing vehicles and lane changes per vehicle;
median time in view; mean ``|xVelocity|`` [m/s] per class and per lane (numbered per carriageway from its
leftmost lane, 1); time headway [s] percentiles over rows with a preceding vehicle and the share under 1 s.
``PUBLISHED_HIGHD`` holds only values found in the cited sources; the rest print as "–".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import pandas as pd

from letspi.highd.schema import DRIVING_DIRECTION_LOWER
from letspi.highd.types import Recording

PAPER: Final = ("Krajewski, Bock, Kloeker, Eckstein: The highD Dataset: A Drone Dataset of Naturalistic Vehicle "
                "Trajectories on German Highways for Validation of Highly Automated Driving Systems. IEEE ITSC 2018, "
                "pp. 2118-2125, doi 10.1109/ITSC.2018.8569552")


@dataclass(frozen=True)
class Published:
    """A published value and where it is from."""

    value: float
    source: str


#: what the highD authors published (abstract of the paper; the dataset's web page as quoted in the
#: Tactics2D documentation), and one recording's own meta file
PUBLISHED_HIGHD: Final[dict[str, Published]] = {
    "vehicles": Published(110_000, "paper abstract: 110 000 vehicles, 16.5 h, 45 000 km, six locations"),
    "lane_changes_per_vehicle": Published(
        5_600 / 110_000, "paper abstract: 5600 complete lane changes among 110 000 vehicles (at most this share "
                         "of vehicles changes lanes)"),
    "lane_changer_share": Published(5_600 / 110_000, "upper bound from the same counts"),
    "median_time_in_view_s": Published(13.6, "highD web page: each vehicle is visible for a median 13.6 s "
                                              "on the ~420 m segment"),
    "truck_share": Published(184 / 1047, "recording 01's recordingMeta (numVehicles 1047, numTrucks 184): one "
                                         "recording, not the dataset"),
}


def _lane_rank(tracks: pd.DataFrame, direction: np.ndarray) -> np.ndarray:
    """(N,) lane of each row numbered per carriageway from its leftmost lane (1), as the direction drives."""
    lane = tracks["laneId"].to_numpy()
    out = np.zeros(len(lane), dtype=np.int64)
    for d in (1, 2):
        sel = direction == d
        if not sel.any():
            continue
        ids = np.unique(lane[sel])
        pos = np.searchsorted(ids, lane[sel])
        # direction 2 drives on the lower lanes, its left is the smaller laneId; direction 1's the larger
        out[sel] = pos + 1 if d == DRIVING_DIRECTION_LOWER else len(ids) - pos
    return out


def traffic_marginals(recordings: Sequence[Recording]) -> dict[str, Any]:
    """The marginals of the module docstring over all ``recordings``."""
    metas = pd.concat([r.tracks_meta for r in recordings], ignore_index=True)
    rate = float(recordings[0].frame_rate_hz) if recordings else 25.0
    speeds: dict[str, list[np.ndarray]] = {"Car": [], "Truck": []}
    lanes: dict[int, list[np.ndarray]] = {}
    thw: list[np.ndarray] = []
    for rec in recordings:
        tm = rec.tracks_meta.set_index("id")
        tr = rec.tracks
        cls = tm.loc[tr["id"], "class"].to_numpy()
        direction = tm.loc[tr["id"], "drivingDirection"].to_numpy()
        speed = np.abs(tr["xVelocity"].to_numpy())
        for c in speeds:
            speeds[c].append(speed[cls == c])
        rank = _lane_rank(tr, direction)
        for k in np.unique(rank):
            lanes.setdefault(int(k), []).append(speed[rank == k])
        h = tr["thw"].to_numpy()
        thw.append(h[h > 0])
    all_thw = np.concatenate(thw) if thw else np.zeros(0)
    n = len(metas)
    out: dict[str, Any] = {
        "vehicles": n,
        "recorded_minutes": sum(float(str(r.meta["duration"])) for r in recordings) / 60.0,
        "truck_share": float((metas["class"] == "Truck").mean()) if n else float("nan"),
        "lane_changer_share": float((metas["numLaneChanges"] > 0).mean()) if n else float("nan"),
        "lane_changes_per_vehicle": float(metas["numLaneChanges"].mean()) if n else float("nan"),
        "median_time_in_view_s": float(np.median(metas["numFrames"]) / rate) if n else float("nan"),
    }
    for c, parts in speeds.items():
        v = np.concatenate(parts) if parts else np.zeros(0)
        out[f"mean_speed_{c.lower()}_mps"] = float(v.mean()) if len(v) else float("nan")
    for k in sorted(lanes):
        out[f"mean_speed_lane{k}_mps"] = float(np.concatenate(lanes[k]).mean())
    if len(all_thw):
        p5, p50, p95 = np.percentile(all_thw, [5, 50, 95])
        out.update(thw_p5_s=float(p5), thw_median_s=float(p50), thw_p95_s=float(p95),
                   thw_below_1s_share=float((all_thw < 1.0).mean()))
    return out


def compare_table(measured: dict[str, dict[str, Any]]) -> str:
    """Markdown table: each measured directory beside the published value and its source."""
    names = list(measured)
    keys = list(dict.fromkeys(k for m in measured.values() for k in m))
    lines = ["| measure | " + " | ".join(names) + " | highD published | source |",
             "|---|" + "---:|" * len(names) + "---:|---|"]
    for key in keys:
        pub = PUBLISHED_HIGHD.get(key)
        cells = [_fmt(key, m.get(key)) for m in measured.values()]
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {_fmt(key, pub.value) if pub else '–'} | "
                     f"{pub.source if pub else 'not published as a number'} |")
    lines.append(f"\nhighD: {PAPER}.")
    return "\n".join(lines)


def _fmt(key: str, value: Any) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    if key.endswith("share"):
        return f"{100 * value:.2f} %"
    if isinstance(value, int) or key == "vehicles":
        return f"{int(value):,d}"
    return f"{value:.3g}" if key == "lane_changes_per_vehicle" else f"{value:.2f}"
