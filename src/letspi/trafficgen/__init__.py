"""HighD-format recordings of a two-direction highway simulated with SUMO; entry point ``generate_highd``."""

from letspi.trafficgen.generate import default_flow_veh_per_h, generate_highd, simulate_recordings

__all__ = ["default_flow_veh_per_h", "generate_highd", "simulate_recordings"]
