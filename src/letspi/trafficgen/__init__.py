"""letspi.trafficgen: HighD-format recordings of a two-direction highway simulated with SUMO (critical events, layouts).

Public entry point: :func:`letspi.trafficgen.generate.generate_highd` (re-exported here).
"""

from letspi.trafficgen.generate import default_flow_veh_per_h, generate_highd, simulate_recordings

__all__ = ["default_flow_veh_per_h", "generate_highd", "simulate_recordings"]
