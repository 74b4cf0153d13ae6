"""Independent check of the recordings' TTC against SUMO's own SSM device (``ssm_check``): per (follower, leader,
frame) where both exist, and per vehicle ``minTTC`` against SUMO's minimum over its recorded frames."""

from __future__ import annotations

import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.highd.derive import build_recording
from letspi.highd.io import write_recording
from letspi.trafficgen.config import TrafficConfig
from letspi.trafficgen.generate import FRAME_RATE_HZ, simulate_recordings
from letspi.trafficgen.simulate import STEP_S

_FOLLOWING_TYPES = {2: "ego", 3: "foe"}  # encounter type -> who is the follower
SSM_TTC_THRESHOLD_S = 5.0  # the device's TTC threshold set in simulate.run_sumo


def read_ssm_ttc(path: Path) -> pd.DataFrame:
    """Per-step TTC of all lead/follow encounters of an SSM output file: ``time_s``, ``follower``, ``leader`` (SUMO
    ids), ``ttc_s``; one row per step with a defined TTC, pairs seen by both devices once."""
    rows: list[pd.DataFrame] = []
    for _, elem in ET.iterparse(path, events=("end",)):
        if elem.tag != "conflict":
            continue
        spans = {child.tag: child.get("values", "").split() for child in elem}
        times, types, ttcs = spans.get("timeSpan"), spans.get("typeSpan"), spans.get("TTCSpan")
        if times and types and ttcs:
            kind = np.asarray(types, dtype=np.int64)
            ttc = pd.to_numeric(pd.Series(ttcs), errors="coerce").to_numpy()  # "NA" -> NaN
            ok = np.isin(kind, list(_FOLLOWING_TYPES)) & np.isfinite(ttc)
            ego, foe = elem.get("ego", ""), elem.get("foe", "")
            follower = np.where(kind == 2, ego, foe)
            leader = np.where(kind == 2, foe, ego)
            rows.append(pd.DataFrame({"time_s": np.asarray(times, dtype=np.float64)[ok], "follower": follower[ok],
                                      "leader": leader[ok], "ttc_s": ttc[ok]}))
        elem.clear()
    if not rows:
        return pd.DataFrame(columns=["time_s", "follower", "leader", "ttc_s"])
    out = pd.concat(rows, ignore_index=True)
    return out.drop_duplicates(["time_s", "follower", "leader"]).reset_index(drop=True)


@dataclass(frozen=True)
class SsmComparison:
    """Agreement of a recording's TTC with SUMO's SSM device, for TTCs below the device threshold (5 s).
    ``frames_both``: (follower, frame) pairs both have for the same leader, ``frame_*``: median and p95 |difference|
    [s], share within 5 %. ``frames_only_*``: pairs only one has; of SUMO's, ``_other_lane`` (a lane changer),
    ``_above_threshold`` (the recording's TTC is >= 5 s) and ``_not_preceding`` (HighD's leader is another).
    ``vehicles_below_3s_*``: minimum under 3 s in the recording, SUMO, both; ``vehicle_median_abs_diff_s`` over both."""

    recorded_minutes: float
    vehicles: int
    frames_both: int
    frame_median_abs_diff_s: float
    frame_p95_abs_diff_s: float
    frame_within_5pct: float
    frames_only_recording: int
    frames_only_ssm: int
    frames_only_ssm_other_lane: int
    frames_only_ssm_above_threshold: int
    frames_only_ssm_not_preceding: int
    vehicles_below_3s_recording: int
    vehicles_below_3s_ssm: int
    vehicles_below_3s_both: int
    vehicle_median_abs_diff_s: float

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def compare_ttc(tracks: pd.DataFrame, tracks_meta: pd.DataFrame, id_of: dict[str, int], ssm: pd.DataFrame,
                first_step: int, recorded_minutes: float) -> SsmComparison:
    """Compare a recording (HighD tracks/tracksMeta, SUMO id -> HighD id) with SSM TTC rows."""
    thr = SSM_TTC_THRESHOLD_S
    s = ssm.assign(frame=np.rint(ssm["time_s"].to_numpy(np.float64) / STEP_S).astype(np.int64) - first_step + 1,
                   id=ssm["follower"].map(id_of), leader_id=ssm["leader"].map(id_of))
    s = s.dropna(subset=["id", "leader_id"]).astype({"id": np.int64, "leader_id": np.int64})
    present = tracks[["id", "frame"]]
    s = s.merge(present, on=["id", "frame"]).merge(present.rename(columns={"id": "leader_id"}),
                                                     on=["leader_id", "frame"])
    s = s[s["ttc_s"] < thr]
    ours_all = tracks.loc[tracks["ttc"] > 0, ["id", "frame", "precedingId", "ttc"]]
    ours_all = ours_all.rename(columns={"precedingId": "leader_id"})
    ours = ours_all[ours_all["ttc"] < thr]
    both = ours.merge(s[["id", "frame", "leader_id", "ttc_s"]], on=["id", "frame", "leader_id"])
    diff = np.abs(both["ttc"].to_numpy() - both["ttc_s"].to_numpy())
    keys_ours = set(zip(ours["id"], ours["frame"], strict=True))
    keys_ssm = set(zip(s["id"], s["frame"], strict=True))
    keys_both = set(zip(both["id"], both["frame"], strict=True))
    lane = tracks.set_index(["id", "frame"])["laneId"]
    only_ssm = s[[k not in keys_both for k in zip(s["id"], s["frame"], strict=True)]]
    only_ssm = only_ssm.drop_duplicates(["id", "frame"])
    follower_keys = list(zip(only_ssm["id"], only_ssm["frame"], strict=True))
    differs = (lane.loc[follower_keys].to_numpy()
               != lane.loc[list(zip(only_ssm["leader_id"], only_ssm["frame"], strict=True))].to_numpy())
    other_lane = int(np.sum(differs))
    preceding = tracks.set_index(["id", "frame"])["precedingId"].loc[follower_keys].to_numpy()
    not_preceding = int(np.sum(~differs & (preceding != only_ssm["leader_id"].to_numpy())))
    above = len(only_ssm.merge(ours_all[ours_all["ttc"] >= thr], on=["id", "frame", "leader_id"]))

    meta = tracks_meta.set_index("id")["minTTC"]
    rec_low = set(meta.index[(meta >= 0) & (meta < 3.0)])
    ssm_min = s.groupby("id")["ttc_s"].min()
    ssm_low = set(ssm_min.index[ssm_min < 3.0])
    common = sorted(rec_low & ssm_low)
    vdiff = np.abs(meta.loc[common].to_numpy() - ssm_min.loc[common].to_numpy()) if common else np.array([])
    return SsmComparison(
        recorded_minutes=recorded_minutes,
        vehicles=len(tracks_meta),
        frames_both=len(both),
        frame_median_abs_diff_s=float(np.median(diff)) if len(diff) else float("nan"),
        frame_p95_abs_diff_s=float(np.percentile(diff, 95)) if len(diff) else float("nan"),
        frame_within_5pct=float(np.mean(diff <= 0.05 * both["ttc_s"].to_numpy())) if len(diff) else float("nan"),
        frames_only_recording=len(keys_ours - keys_both),
        frames_only_ssm=len(keys_ssm - keys_both),
        frames_only_ssm_other_lane=other_lane,
        frames_only_ssm_above_threshold=above,
        frames_only_ssm_not_preceding=not_preceding,
        vehicles_below_3s_recording=len(rec_low),
        vehicles_below_3s_ssm=len(ssm_low),
        vehicles_below_3s_both=len(common),
        vehicle_median_abs_diff_s=float(np.median(vdiff)) if len(vdiff) else float("nan"),
    )


def ssm_check(*, minutes: float, seed: int, traffic: TrafficConfig, lanes_per_direction: int = 3,
              keep_dir: Path | None = None, progress: Callable[[float], None] | None = None) -> SsmComparison:
    """Simulate one recording with SUMO's SSM device on every vehicle and compare TTCs (``compare_ttc``);
    ``keep_dir``: where to keep the SSM XML and the HighD files."""

    work = Path(tempfile.mkdtemp(prefix="letspi_ssm_"))
    try:
        ssm_file = work / "ssm.xml"
        sim = simulate_recordings(minutes=minutes, seed=seed, lanes_per_direction=lanes_per_direction,
                                  traffic=traffic, ssm_file=ssm_file, progress=progress)
        states, vehicles = sim.chunks[0]
        rec = build_recording(states, vehicles[["id", "class", "drivingDirection"]], recording_id=1,
                              upper_markings_y_m=sim.network.upper_markings_y_m.tolist(),
                              lower_markings_y_m=sim.network.lower_markings_y_m.tolist(),
                              frame_rate_hz=FRAME_RATE_HZ)
        ssm = read_ssm_ttc(ssm_file)
        if keep_dir is not None:
            keep = Path(keep_dir)
            keep.mkdir(parents=True, exist_ok=True)
            write_recording(rec, keep)
            shutil.copy(ssm_file, keep / "01_ssm.xml")
            vehicles[["id", "sumo_id"]].to_csv(keep / "01_sumo_ids.csv", index=False)
        id_of = dict(zip(vehicles["sumo_id"], vehicles["id"], strict=True))
        return compare_ttc(rec.tracks, rec.tracks_meta, id_of, ssm, sim.first_steps[0], float(minutes))
    finally:
        shutil.rmtree(work, ignore_errors=True)
