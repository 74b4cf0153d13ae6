"""letspi.sumo: HighD-format recordings of a straight two-direction highway simulated with SUMO.

Public entry point: :func:`letspi.sumo.generate.generate_recordings` (re-exported here).
"""

from letspi.sumo.generate import default_flow_veh_per_h, generate_recordings, simulate_recordings

__all__ = ["default_flow_veh_per_h", "generate_recordings", "simulate_recordings"]
