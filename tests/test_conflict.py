"""The one TTC / DRAC formula (letspi.conflict), with the conventions its callers pass in."""

from __future__ import annotations

import numpy as np

from letspi.conflict import deceleration_to_avoid_crash_mps2, time_to_collision_s


def test_ttc_closing_in_contact_and_not_closing() -> None:
    gap = np.array([20.0, 20.0, 0.0, -1.0, 20.0, np.inf])
    closing = np.array([4.0, -2.0, 3.0, 3.0, np.nan, np.nan])
    np.testing.assert_array_equal(time_to_collision_s(gap, closing), [5.0, np.inf, 0.0, 0.0, np.inf, np.inf])
    # highD's tracks write 0 where TTC is undefined
    np.testing.assert_array_equal(time_to_collision_s(gap, closing, not_closing_s=0.0), [5.0, 0, 0, 0, 0, 0])


def test_drac_is_the_constant_deceleration_that_just_avoids_contact() -> None:
    gap = np.array([20.0, 20.0, 0.0, np.inf, 20.0])
    closing = np.array([4.0, -2.0, 3.0, 5.0, np.nan])
    drac = deceleration_to_avoid_crash_mps2(gap, closing)
    np.testing.assert_array_equal(drac, [0.4, 0.0, np.inf, 0.0, 0.0])
    # braking at DRAC from closing speed dv stops closing after dv / a seconds, having used exactly the gap
    dv, a = 4.0, drac[0]
    assert dv * (dv / a) - 0.5 * a * (dv / a) ** 2 == 20.0
    assert deceleration_to_avoid_crash_mps2(np.array([0.0]), np.array([3.0]), contact_mps2=0.0)[0] == 0.0
