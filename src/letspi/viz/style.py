"""Shared look of every picture: fonts, the Okabe–Ito colour-blind-safe palette, one colour per role: ego black
(truth dashed), planner k ``PLAN_COLOURS[k]``, neighbours orange (same lane), sky blue (adjacent) or grey (future
dashed), goal a vermillion star, adjusted goal a diamond. Artists carry a ``gid`` (``gid_*``)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Final

import matplotlib as mpl
from cycler import cycler

#: Okabe & Ito (2008), "Color Universal Design": distinguishable with the common colour-vision deficiencies.
OKABE_ITO: Final = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky_blue": "#56B4E9",
    "bluish_green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish_purple": "#CC79A7",
}

EGO_PAST: Final = OKABE_ITO["black"]
EGO_TRUTH: Final = OKABE_ITO["black"]
NBR_SAME_LANE: Final = OKABE_ITO["orange"]
NBR_ADJACENT_LANE: Final = OKABE_ITO["sky_blue"]
NBR_OTHER: Final = "#8C8C8C"
GOAL: Final = OKABE_ITO["vermillion"]
LANE_LINE: Final = "#6E6E6E"
ROAD_EDGE: Final = "#303030"
ROAD_FILL: Final = "#F4F4F4"
TEXT_BOX_FACE: Final = "#FAFAFA"
ALERT: Final = OKABE_ITO["vermillion"]

#: Colours of the plans, in the order planners are given (yellow is left out: too faint on white).
PLAN_COLOURS: Final = (
    OKABE_ITO["blue"],
    OKABE_ITO["bluish_green"],
    OKABE_ITO["reddish_purple"],
    OKABE_ITO["vermillion"],
    OKABE_ITO["sky_blue"],
    OKABE_ITO["orange"],
)

#: Dashes of the ground-truth future (ego and neighbours).
TRUTH_STYLE: Final = (0, (5.0, 2.5))

BASE_FONT_SIZE: Final = 10.0
RC: Final[dict] = {  # type: ignore[type-arg]
    "font.size": BASE_FONT_SIZE,
    "axes.titlesize": BASE_FONT_SIZE + 1,
    "axes.titleweight": "bold",
    "axes.labelsize": BASE_FONT_SIZE,
    "xtick.labelsize": BASE_FONT_SIZE - 1,
    "ytick.labelsize": BASE_FONT_SIZE - 1,
    "legend.fontsize": BASE_FONT_SIZE - 1,
    "legend.framealpha": 0.92,
    "axes.grid": True,
    "grid.color": "#DDDDDD",
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.prop_cycle": cycler(color=list(PLAN_COLOURS)),
    "savefig.dpi": 130,
    "savefig.bbox": "tight",
    "figure.dpi": 100,
    "font.family": "DejaVu Sans",
}


@contextmanager
def letspi_style() -> Iterator[None]:
    """Apply the letspi rcParams while building a figure (restores the caller's afterwards)."""
    with mpl.rc_context(RC):  # type: ignore[arg-type]
        yield


def plan_colour(k: int) -> str:
    """Colour of the ``k``-th plan (cycles after six)."""
    return PLAN_COLOURS[k % len(PLAN_COLOURS)]


def gid_plan(name: str) -> str:
    """gid of a plan's line (trajectory diagram; ``ts:`` prefixed in the time-space diagram)."""
    return f"plan:{name}"


def gid_nbr(kind: str, vehicle_id: int) -> str:
    """gid of a neighbour artist: ``kind`` is ``past``, ``future`` or ``box``."""
    return f"nbr_{kind}:{vehicle_id}"


def gid_marking(k: int, is_edge: bool) -> str:
    """gid of lane marking ``k`` (ascending y): ``road_edge:k`` or ``lane_line:k``."""
    return f"{'road_edge' if is_edge else 'lane_line'}:{k}"
