"""The prompt text the method layer writes (safety reports, memory examples), rendered for fixed inputs: part of
the prompt fingerprint (``prompt_fingerprint(prompt_text_samples())``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Final

from letspi.constants import DT_S, N_FUTURE
from letspi.method.memory import Experience
from letspi.method.phases import compact_report, memory_example
from letspi.method.reflection import METRIC_ORDER, MetricName, Proposal, Relative, SafetyReport, Violation
from letspi.method.thresholds import ReflectionThresholds
from letspi.physics.params import SocialForceParams

_INF: Final = float("inf")
#: One violation of each kind: metric -> (value, threshold, unit, step, neighbour slot, vehicle id,
#: neighbour lane, ego lane, where the neighbour is, dx m, dy m).
_VIOLATIONS: Final[dict[str, tuple[float, float, str, int, int, int, int, int, Relative, float, float]]] = {
    "contact": (0.0, 2.0, "m", 30, 1, 7, 5, 6, "left", 1.5, 2.1),
    "front_ttc": (1.12, 1.5, "s", 19, 0, 3, 6, 6, "front", 14.2, 0.1),
    "rear_ttc": (0.91, 1.5, "s", 44, 2, 9, 6, 6, "rear", -8.4, -0.2),
    "in_path_gap": (1.36, 2.0, "m", 61, 0, 3, 6, 6, "front", 5.9, 0.0),
    "pet": (0.42, 1.0, "s", 70, 3, 11, 7, 6, "right", 3.3, -3.6),
    "off_road": (0.37, 0.0, "m", 88, -1, 0, 0, 0, "none", math.nan, math.nan),
    "harsh_braking": (9.3, 8.0, "m/s^2", 12, -1, 0, 0, 6, "none", math.nan, math.nan),
}
_METRICS: Final = {"min_ttc_s": 1.12, "min_rear_ttc_s": 0.91, "min_path_gap_m": 0.0, "min_box_gap_m": 0.0,
                   "collision": 1.0, "off_road": 1.0, "min_pet_s": 0.42, "safe": 0.0, "max_decel_mps2": 9.3}
_PRE_CONTACT: Final = {**_METRICS, "min_path_gap_m": 1.36, "min_box_gap_m": 0.6, "collision": 0.0}
_SAFE: Final = {"min_ttc_s": _INF, "min_rear_ttc_s": 6.4, "min_path_gap_m": 31.5, "min_box_gap_m": 2.7,
                "collision": 0.0, "off_road": 0.0, "safe": 1.0, "max_decel_mps2": 1.1}


def _violation(metric: MetricName) -> Violation:
    value, threshold, unit, step, slot, vid, nbr_lane, ego_lane, rel, dx, dy = _VIOLATIONS[metric]
    return Violation(metric, value, threshold, unit, step, (step + 1) * DT_S, slot, vid, nbr_lane, ego_lane, rel,
                     dx, dy)


def _proposal() -> Proposal:
    params = SocialForceParams(tau_s=1.4, k_np=14.0, k_nf=6.0, k_nl=2.5, k_boundary=1.2, k_cline=0.9, r_col_m=7.5)
    return Proposal(params=params, lon_factor=0.7, lane_factor=0.25, rationale="leader brakes")


def _experience(lane_change: float, metrics_after: Mapping[str, object]) -> Experience:
    features = (5.0, 27.34, lane_change, 11.26, 38.92, 25.07)
    p = _proposal()
    return Experience("fp", "digest", "key", 1, 2, 3, "config", features, p.params, p.lon_factor, p.lane_factor,
                      {}, dict(metrics_after), [], "model", None, None, p.rationale, validated=True)


def prompt_text_samples() -> dict[str, str]:
    """Every sample text by name: safety reports (paper and compact form) and memory examples; ``RuntimeError``
    for a violation kind of ``METRIC_ORDER`` without a sample."""
    missing = [m for m in METRIC_ORDER if m not in _VIOLATIONS]
    if missing:
        raise RuntimeError(f"violation kind(s) {', '.join(missing)} have no prompt sample: add them to "
                           "letspi.method.prompt_samples._VIOLATIONS")
    all_checks = ReflectionThresholds(pet_s=1.0, check_off_road=True, max_decel_mps2=8.0)
    few_checks = ReflectionThresholds(pet_s=None, check_off_road=False, max_decel_mps2=None)
    unsafe = SafetyReport("fp", tuple(_violation(m) for m in METRIC_ORDER), dict(_METRICS), all_checks, N_FUTURE,
                          pre_contact_metrics=dict(_PRE_CONTACT), first_contact_time_s=1.24)
    front = SafetyReport("fp", (_violation("front_ttc"), _violation("in_path_gap")), {**_SAFE, "safe": 0.0},
                         few_checks, N_FUTURE)
    safe = SafetyReport("fp", (), dict(_SAFE), few_checks, N_FUTURE)
    out = {
        "report/unsafe": unsafe.to_text(),
        "report/unsafe+proposal": unsafe.to_text(_proposal()),
        "report/front+proposal": front.to_text(_proposal()),
        "report/safe": safe.to_text(),
        "compact-report/unsafe": compact_report(unsafe),
        "compact-report/front": compact_report(front),
        "compact-report/safe": compact_report(safe),
    }
    for name, lane_change, after in (("keep", 0.0, _SAFE), ("change", 1.0, {"min_ttc_s": "n/a"})):
        example = memory_example(_experience(lane_change, after))
        out[f"memory/{name}"] = f"{example.summary} ({example.outcome}): {example.answer('fast')}"
    return out
