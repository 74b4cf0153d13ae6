"""Criticality profile of HighD recordings: how much conflict the recorded traffic contains.

Per vehicle: ``minTTC`` [s], ``minTHW`` [s], ``minDHW`` [m] from tracksMeta (-1 = no value) and ``maxDRAC``
[m/s²] computed here: the largest closing_speed² / (2 · dhw) while closing in on a preceding vehicle (closing
speed = |xVelocity| - |precedingXVelocity|). Shares are of **all** vehicles ("under 3 s" = ``0 <= minTTC < 3``).
Flow per lane counts crossings of the middle of the recorded x range, per hour of recording.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from letspi.conflict import deceleration_to_avoid_crash_mps2
from letspi.highd.contacts import overlapping_boxes
from letspi.highd.events import read_events
from letspi.highd.io import read_recordings
from letspi.highd.types import Recording

__all__ = [
    "CriticalityProfile",
    "MeasureSummary",
    "criticality_profile",
    "lane_flows",
    "profile_directory",
    "profile_table",
    "vehicle_criticality",
]

TTC_THRESHOLDS_S: tuple[float, ...] = (1.5, 3.0)
THW_THRESHOLDS_S: tuple[float, ...] = (0.5, 1.0, 1.5, 3.0)
DHW_THRESHOLDS_M: tuple[float, ...] = (5.0, 10.0)
DRAC_THRESHOLD_MPS2 = 3.0  # SUMO's SSM default conflict threshold


@dataclass(frozen=True)
class MeasureSummary:
    """Distribution of one per-vehicle minimum: ``n_defined`` vehicles with a value (not -1); ``share_below``
    threshold text (``"3"``) -> share of all vehicles with ``0 <= value < threshold``; ``p5`` and ``median``
    over the defined values (NaN if none)."""

    n_defined: int
    share_below: dict[str, float]
    p5: float
    median: float


@dataclass(frozen=True)
class CriticalityProfile:
    """Summary of one or more recordings (definitions in the module docstring); shares are of all vehicles.
    ``drac_above_3_share``: max DRAC > 3 m/s². ``flow_veh_per_h_by_lane``: laneId -> vehicles per hour.
    ``contact_pairs``: distinct pairs whose boxes overlap at least once; ``contact_frames``: (pair, frame) overlaps.
    ``events_by_kind``: scripted events per kind (empty without events files). ``event_vehicle_share``: vehicles that
    act in or react to an event (``id``/``other_id``); ``low_ttc_event_share``: of the vehicles with 0 <= minTTC < 3 s,
    the share that are event vehicles (NaN if none)."""

    n_recordings: int
    recorded_minutes: float
    n_vehicles: int
    truck_share: float
    min_ttc_s: MeasureSummary
    min_thw_s: MeasureSummary
    min_dhw_m: MeasureSummary
    drac_above_3_share: float
    lane_changes_per_vehicle: float
    lane_changer_share: float
    flow_veh_per_h_by_lane: dict[int, float]
    contact_pairs: int
    contact_frames: int
    events_by_kind: dict[str, int] = field(default_factory=dict)
    event_vehicle_share: float = 0.0
    low_ttc_event_share: float = float("nan")

    def to_dict(self) -> dict[str, object]:
        """JSON-ready dict (lane keys become strings)."""
        out = asdict(self)
        out["flow_veh_per_h_by_lane"] = {str(k): v for k, v in self.flow_veh_per_h_by_lane.items()}
        return out


def vehicle_criticality(rec: Recording) -> pd.DataFrame:
    """Per-vehicle criticality of one recording: tracksMeta's ``id, class, drivingDirection, minTTC, minTHW,
    minDHW, numLaneChanges`` and ``maxDRAC`` [m/s²] (0 when never closing in)."""
    tr = rec.tracks
    vx = tr["xVelocity"].to_numpy(np.float64)
    prec_vx = tr["precedingXVelocity"].to_numpy(np.float64)
    dhw = tr["dhw"].to_numpy(np.float64)
    has_prec = tr["precedingId"].to_numpy() > 0
    closing = np.abs(vx) - np.abs(prec_vx)
    drac = np.where(has_prec, deceleration_to_avoid_crash_mps2(dhw, closing, contact_mps2=0.0), 0.0)
    max_drac = pd.Series(drac).groupby(tr["id"].to_numpy()).max()
    cols = ["id", "class", "drivingDirection", "minTTC", "minTHW", "minDHW", "numLaneChanges"]
    out = rec.tracks_meta[cols].copy()
    out["maxDRAC"] = out["id"].map(max_drac).fillna(0.0).to_numpy(np.float64)
    return out.reset_index(drop=True)


def lane_flows(rec: Recording) -> tuple[pd.Series, float]:
    """Vehicles crossing the middle of the recorded x range, by laneId, and the recording's duration [h]."""
    tr = rec.tracks  # sorted by (id, frame)
    cx = tr["x"].to_numpy(np.float64) + tr["width"].to_numpy(np.float64) / 2.0
    x_mid = 0.5 * (float(tr["x"].min()) + float((tr["x"] + tr["width"]).max()))
    ids = tr["id"].to_numpy()
    side = cx >= x_mid
    crossed = (ids[1:] == ids[:-1]) & (side[1:] != side[:-1])
    lanes = tr["laneId"].to_numpy()[1:][crossed]
    counts = pd.Series(lanes).value_counts().sort_index()
    duration_h = float(rec.meta["duration"]) / 3600.0  # type: ignore[arg-type]
    return counts, duration_h


def _summary(values: np.ndarray, thresholds: Sequence[float], n_all: int) -> MeasureSummary:
    defined = values[values >= 0.0]
    shares = {f"{t:g}": float(np.sum(defined < t)) / max(n_all, 1) for t in thresholds}
    if len(defined) == 0:
        return MeasureSummary(0, shares, float("nan"), float("nan"))
    return MeasureSummary(len(defined), shares, float(np.percentile(defined, 5)), float(np.median(defined)))


def criticality_profile(recordings: Sequence[Recording],
                        events: Sequence[pd.DataFrame | None] | None = None) -> CriticalityProfile:
    """Profile of recordings taken together (vehicles pooled, flows over the summed durations). ``events``: each
    recording's ``NN_events.csv`` table (None where absent), same order. ValueError without recordings."""
    if not recordings:
        raise ValueError("no recordings to profile")
    per_vehicle = pd.concat([vehicle_criticality(r) for r in recordings], ignore_index=True)
    n = len(per_vehicle)
    lane_counts: dict[int, float] = {}
    hours = 0.0
    pairs = frames = 0
    for rec in recordings:
        counts, duration_h = lane_flows(rec)
        hours += duration_h
        for lane, c in zip(counts.index.to_numpy(), counts.to_numpy(), strict=True):
            lane_counts[int(lane)] = lane_counts.get(int(lane), 0.0) + float(c)
        overlaps = overlapping_boxes(rec.tracks)
        frames += len(overlaps)
        pairs += len(overlaps[["id_a", "id_b"]].drop_duplicates())
    by_kind: dict[str, int] = {}
    involved = np.zeros(n, dtype=bool)
    rec_of_row = np.repeat(np.arange(len(recordings)), [len(r.tracks_meta) for r in recordings])
    for k, ev in enumerate(events or []):
        if ev is None:
            continue
        for kind, c in zip(*np.unique(ev["kind"].to_numpy(str), return_counts=True), strict=True):
            by_kind[str(kind)] = by_kind.get(str(kind), 0) + int(c)
        ids = np.union1d(ev["id"].to_numpy(), ev["other_id"].to_numpy())
        involved |= (rec_of_row == k) & np.isin(per_vehicle["id"].to_numpy(), ids)
    ttc = per_vehicle["minTTC"].to_numpy(np.float64)
    low = (ttc >= 0.0) & (ttc < 3.0)
    lc = per_vehicle["numLaneChanges"].to_numpy()
    return CriticalityProfile(
        n_recordings=len(recordings),
        recorded_minutes=60.0 * hours,
        n_vehicles=n,
        truck_share=float((per_vehicle["class"] == "Truck").mean()) if n else 0.0,
        min_ttc_s=_summary(per_vehicle["minTTC"].to_numpy(np.float64), TTC_THRESHOLDS_S, n),
        min_thw_s=_summary(per_vehicle["minTHW"].to_numpy(np.float64), THW_THRESHOLDS_S, n),
        min_dhw_m=_summary(per_vehicle["minDHW"].to_numpy(np.float64), DHW_THRESHOLDS_M, n),
        drac_above_3_share=float(np.mean(per_vehicle["maxDRAC"].to_numpy() > DRAC_THRESHOLD_MPS2)) if n else 0.0,
        lane_changes_per_vehicle=float(lc.mean()) if n else 0.0,
        lane_changer_share=float(np.mean(lc > 0)) if n else 0.0,
        flow_veh_per_h_by_lane={k: v / hours for k, v in sorted(lane_counts.items())} if hours > 0 else {},
        contact_pairs=pairs,
        contact_frames=frames,
        events_by_kind=dict(sorted(by_kind.items())),
        event_vehicle_share=float(involved.mean()) if n else 0.0,
        low_ttc_event_share=float(involved[low].mean()) if low.any() else float("nan"),
    )


def profile_directory(directory: Path, ids: Sequence[int] | None = None) -> CriticalityProfile:
    """Read the recordings (and events files) of a HighD directory and profile them."""

    recs = read_recordings(Path(directory), ids)
    return criticality_profile(recs, [read_events(Path(directory), r.recording_id) for r in recs])


def _pct(x: float) -> str:
    return f"{100.0 * x:.2f} %"


def _num(x: float, unit: str) -> str:
    return "-" if np.isnan(x) else f"{x:.2f} {unit}"


def profile_table(profiles: dict[str, CriticalityProfile]) -> str:
    """Markdown table of one or more profiles side by side (one column per profile)."""
    names = list(profiles)
    ps = [profiles[n] for n in names]
    rows: list[tuple[str, list[str]]] = [
        ("recordings / minutes", [f"{p.n_recordings} / {p.recorded_minutes:.1f}" for p in ps]),
        ("vehicles", [str(p.n_vehicles) for p in ps]),
        ("truck share", [_pct(p.truck_share) for p in ps]),
    ]
    for label, attr, unit in (("minTTC", "min_ttc_s", "s"), ("minTHW", "min_thw_s", "s"), ("minDHW", "min_dhw_m", "m")):
        summaries = [getattr(p, attr) for p in ps]
        for thr in summaries[0].share_below:
            rows.append((f"{label} < {thr} {unit} (share of vehicles)", [_pct(m.share_below[thr]) for m in summaries]))
        rows.append((f"{label} p5 / median", [f"{_num(m.p5, unit)} / {_num(m.median, unit)}" for m in summaries]))
    rows += [
        ("max DRAC > 3 m/s² (share of vehicles)", [_pct(p.drac_above_3_share) for p in ps]),
        ("lane changes per vehicle", [f"{p.lane_changes_per_vehicle:.3f}" for p in ps]),
        ("vehicles changing lanes", [_pct(p.lane_changer_share) for p in ps]),
    ]
    lanes = sorted({lane for p in ps for lane in p.flow_veh_per_h_by_lane})
    for lane in lanes:
        rows.append((f"flow laneId {lane} [veh/h]", [f"{p.flow_veh_per_h_by_lane.get(lane, 0.0):.0f}" for p in ps]))
    rows.append(("contacts (vehicle pairs / pair-frames)", [f"{p.contact_pairs} / {p.contact_frames}" for p in ps]))
    kinds = sorted({k for p in ps for k in p.events_by_kind})
    for kind in kinds:
        rows.append((f"events: {kind}", [str(p.events_by_kind.get(kind, 0)) for p in ps]))
    rows.append(("vehicles in a scripted event", [_pct(p.event_vehicle_share) for p in ps]))
    rows.append(("minTTC < 3 s vehicles that are in an event",
                 ["-" if np.isnan(p.low_ttc_event_share) else _pct(p.low_ttc_event_share) for p in ps]))
    header = "| | " + " | ".join(names) + " |"
    rule = "|---|" + "---:|" * len(names)
    return "\n".join([header, rule, *(f"| {label} | " + " | ".join(vals) + " |" for label, vals in rows)])
