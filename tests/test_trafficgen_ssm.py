"""SUMO's SSM device as an independent check of the recordings' TTC."""

from __future__ import annotations

from pathlib import Path

import pytest

from letspi.trafficgen.ssm import read_ssm_ttc

SSM_XML = """<SSMLog>
  <conflict begin="10.00" end="10.12" ego="a" foe="b">
    <timeSpan values="10.00 10.04 10.08 10.12"/>
    <typeSpan values="2 2 4 2"/>
    <TTCSpan values="2.50 2.40 NA 2.30"/>
  </conflict>
  <conflict begin="10.00" end="10.04" ego="b" foe="a">
    <timeSpan values="10.00 10.04"/>
    <typeSpan values="3 3"/>
    <TTCSpan values="2.50 2.40"/>
  </conflict>
  <conflict begin="11.00" end="11.00" ego="c" foe="d">
    <timeSpan values="11.00"/>
    <typeSpan values="10"/>
    <TTCSpan values="1.0"/>
  </conflict>
</SSMLog>
"""


def test_read_ssm_ttc_keeps_following_encounters_once(tmp_path: Path) -> None:
    path = tmp_path / "ssm.xml"
    path.write_text(SSM_XML)
    rows = read_ssm_ttc(path)
    # type 2: ego follows foe; type 3: foe follows ego (the same pair seen from b); NA and
    # adjacent-lane (4) and crossing (10) steps dropped
    assert rows[["time_s", "follower", "leader"]].to_numpy().tolist() == [
        [10.0, "a", "b"], [10.04, "a", "b"], [10.12, "a", "b"]]
    assert rows["ttc_s"].tolist() == [2.5, 2.4, 2.3]


@pytest.mark.sumo
@pytest.mark.slow
def test_recorded_ttc_agrees_with_sumo_ssm() -> None:
    pytest.importorskip("sumo")
    from letspi.trafficgen.config import traffic_preset
    from letspi.trafficgen.ssm import ssm_check

    c = ssm_check(minutes=2.0, seed=0, traffic=traffic_preset("highd"))
    assert c.frames_both > 50 and c.vehicles_below_3s_both >= 1
    assert c.frame_within_5pct > 0.9 and c.frame_median_abs_diff_s < 0.1
    assert c.vehicles_below_3s_both >= 0.8 * max(c.vehicles_below_3s_recording, c.vehicles_below_3s_ssm)
