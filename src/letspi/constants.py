"""Fixed quantities of the planning problem (paper §IV-B).

A scenario holds ``N_TOTAL`` frames; ``T0_INDEX`` is the planning instant t = 0 (the last history frame). History
is ``[0, T0_INDEX]`` (75 frames, 3 s), the future ``[T0_INDEX + 1, N_TOTAL)`` (125 frames, 5 s).
"""

from typing import Final

FRAME_RATE_HZ: Final = 25.0
DT_S: Final = 1.0 / FRAME_RATE_HZ
N_HISTORY: Final = 75
N_FUTURE: Final = 125
N_TOTAL: Final = N_HISTORY + N_FUTURE
T0_INDEX: Final = N_HISTORY - 1
HORIZON_S: Final = N_FUTURE * DT_S
MAX_NEIGHBOURS: Final = 8
NEIGHBOUR_RADIUS_M: Final = 100.0
CONTEXT_RADIUS_M: Final = 150.0
"""Context vehicles (scored, never shown to a planner) come within this distance of the ego's recorded
future track: beyond it no plausible plan reaches them in 5 s (a 30 m/s speed difference)."""
MAX_CONTEXT: Final = 24
DEFAULT_STRIDE_FRAMES: Final = 20
