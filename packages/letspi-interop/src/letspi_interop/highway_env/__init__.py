"""letspi on highway-env (Farama-Foundation/HighwayEnv): the bridge between its simulation and letspi's scenarios.

Needs the extra ``highway`` (``pip install -e "packages/letspi-interop[highway]"``: highway-env, gymnasium, pygame-ce).

* ``scene`` (NumPy only, no highway-env import): the road of an episode (``RoadLayout``), every vehicle's
  recorded states (``EpisodeTracks``), the adapter from them to a letspi scenario (``scenario_view``) and the
  export of an episode as a HighD recording (``episode_recording``);
* ``sim`` (imports highway-env at module level; the rest of letspi imports it only where an episode runs):
  environments made and checked by id and configuration (``make_env``), the egos (``TrackingEgo``, which
  follows letspi's plans, and highway-env's own vehicles as baselines), the swap of the ego after ``reset``
  and the recorder.

``require()`` is the one check that the extra is installed: it ends in one line naming the fix.
"""

from __future__ import annotations

import importlib.util
from typing import Final

#: what to install when highway-env or gymnasium is missing
INSTALL_HINT: Final = 'pip install -e "packages/letspi-interop[highway]"'


class HighwayEnvMissingError(ValueError):
    """highway-env (or gymnasium) is not installed; the message names the extra to install (a setup error: the
    command line prints it in one line)."""


def require() -> None:
    """Raise ``HighwayEnvMissingError`` (one line, naming the extra) unless highway-env and gymnasium import."""
    missing = [name for name in ("highway_env", "gymnasium") if importlib.util.find_spec(name) is None]
    if missing:
        raise HighwayEnvMissingError(f"{' and '.join(missing)} not installed: {INSTALL_HINT}")
