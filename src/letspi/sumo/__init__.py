"""letspi.sumo: HighD-format recordings of a two-direction highway simulated with SUMO (critical events, layouts).

Public entry point: :func:`letspi.sumo.generate.generate_highd` (re-exported here).
"""

from letspi.sumo.generate import default_flow_veh_per_h, generate_highd, simulate_recordings

__all__ = ["default_flow_veh_per_h", "generate_highd", "simulate_recordings"]
