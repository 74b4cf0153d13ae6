"""``--keep-lane``: the rule, the verification and the shield take a preset that changes lane only where every
preset keeping the lane fails more checks (hand-built check tables)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from letspi.method.decide import Decider, OptionChecks, load_presets, preference_order, rule_choice
from letspi.method.thresholds import ReflectionThresholds

NAMES = ("default", "ease", "slow", "brake", "right-slow", "right-brake")
CHANGES_LANE = np.array([False, False, False, False, True, True])


def _checks(failed: list[int], progress: list[float]) -> OptionChecks:
    """One scenario: option k fails ``failed[k]`` adverse futures (the prediction always passes)."""
    k, a = len(failed), 3
    adverse = np.zeros((1, k, a), dtype=bool)
    for i, n in enumerate(failed):
        adverse[0, i, :n] = True
    nan = np.full((1, k, 2, 2), np.nan)
    return OptionChecks(names=NAMES, adverse_names=("leader-brakes", "cut-in", "follower-keeps"),
                        predicted_safe=np.ones((1, k), dtype=bool), adverse_failed=adverse,
                        progress_m=np.array([progress], dtype=np.float64), min_ttc_s=np.full((1, k), 5.0),
                        xy_m=nan, vxy_mps=nan, goals_xy_m=np.full((1, k, 2), np.nan))


def test_the_rule_prefers_a_lane_keeper_among_equally_checked_presets():
    checks = _checks([1, 1, 0, 0, 0, 1], [140.0, 130.0, 120.0, 100.0, 125.0, 110.0])
    args = (checks.predicted_safe, checks.adverse_failed, checks.progress_m)
    assert NAMES[rule_choice(*args)[0]] == "right-slow"  # most progress among those failing nothing
    assert NAMES[rule_choice(*args, CHANGES_LANE)[0]] == "slow"  # the lane keeper failing as few checks
    # a lane change a check demands: every lane keeper fails more
    demanded = _checks([2, 2, 1, 1, 0, 1], [140.0, 130.0, 120.0, 100.0, 125.0, 110.0])
    assert NAMES[rule_choice(demanded.predicted_safe, demanded.adverse_failed, demanded.progress_m,
                             CHANGES_LANE)[0]] == "right-slow"


def test_the_shield_tries_lane_keepers_first():
    passes = np.array([False, True, True, False, True, True])
    progress = np.array([140.0, 130.0, 120.0, 100.0, 135.0, 110.0])
    assert preference_order(passes, progress) == [4, 1, 2, 5]
    assert preference_order(passes, progress, CHANGES_LANE) == [1, 2, 4, 5]


def test_verification_replaces_a_lane_change_a_lane_keeper_matches():
    table, _ = load_presets()
    assert table.names == NAMES and np.array_equal(np.abs(table.values[:, 7]) > 0, CHANGES_LANE)
    decider = Decider(table, 10.0, ReflectionThresholds(), None, None, verify=True)
    checks = _checks([1, 1, 0, 0, 0, 1], [140.0, 130.0, 120.0, 100.0, 125.0, 110.0])
    assert decider.verified(checks, "right-slow") == "right-slow"  # no lane preference: the model's say
    keeping = replace(decider, keep_lane=True)
    assert keeping.verified(checks, "right-slow") == "slow"
    assert keeping.verified(checks, "brake") == "brake"  # a lane keeper failing nothing stands
    demanded = _checks([2, 2, 1, 1, 0, 1], [140.0, 130.0, 120.0, 100.0, 125.0, 110.0])
    assert keeping.verified(demanded, "right-slow") == "right-slow"
