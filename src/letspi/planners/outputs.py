"""What planners report per scenario beside their plans (``PlanBatch.info``): each a ``Metric`` declared once in
the module that produces it and listed by its kinds' ``PlannerKind.outputs``. Results store output ``x`` in
``info_x`` (``column``); an (B, K <= 8) one in ``info_x_0`` ... ``info_x_{K-1}``; closed loop adds
``info_x_mean_over_replans``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Final

import numpy as np

from letspi.metrics.registry import Agg, Dtype, Metric
from letspi.physics.params import PARAM_NAMES, PARAM_UNITS

INFO_PREFIX: Final = "info_"
#: ``Metric.source`` of a column an evaluation mode writes itself, stored under its own name (``n_replans``)
AS_NAMED: Final = "as named"
OVER_REPLANS: Final = "_mean_over_replans"
#: widest 2-D output stored column by column
MAX_OUTPUT_WIDTH: Final = 8


def output(name: str, unit: str, dtype: Dtype, doc: str, *aggregates: Agg) -> Metric:
    """One declared output (``source`` None: the planner supplies it)."""
    return Metric(name, unit, dtype, doc, None, tuple(aggregates))


def column(out: Metric | str) -> str:
    """The results column of an output (or of an output name)."""
    if isinstance(out, Metric):
        return out.name if out.source == AS_NAMED else INFO_PREFIX + out.name
    return INFO_PREFIX + out


def over_replans(out: Metric | str) -> str:
    """The closed-loop column of an output's mean over a window's replans."""
    return column(out) + OVER_REPLANS


def info_columns(info: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``PlanBatch.info`` as results columns: (B,) as ``info_x``, (B, K <= 8) as ``info_x_k``."""
    cols: dict[str, np.ndarray] = {}
    for key, arr in info.items():
        a = np.asarray(arr)
        if a.ndim == 1:
            cols[column(key)] = a
        elif a.ndim == 2 and a.shape[1] <= MAX_OUTPUT_WIDTH:
            for k in range(a.shape[1]):
                cols[f"{column(key)}_{k}"] = a[:, k]
    return cols


def undeclared(info: Mapping[str, object], outputs: Iterable[Metric]) -> list[str]:
    """The keys of ``info`` that no output of ``outputs`` declares."""
    names = {o.name for o in outputs}
    return sorted(k for k in info if k not in names)


def by_column(outputs: Iterable[Metric]) -> dict[str, Metric]:
    """Results column -> output, for the outputs' (B,) columns (later declarations of a name win)."""
    return {column(o): o for o in outputs}


#: the social force parameters a plan was made with (sf, gnp, mlp and the LLM planners)
PARAM_OUTPUTS: Final[tuple[Metric, ...]] = tuple(
    output(name, PARAM_UNITS[name], "float64", f"social force parameter {name} of the plan") for name in PARAM_NAMES)
LON_FACTOR = output("lon_factor", "1", "float64", "goal adjustment in [0, 1]: the goal distance is scaled by "
                    "1.2 - 0.5 f (NaN: none)")
LANE_FACTOR = output("lane_factor", "1", "float64", "goal adjustment in [-1, 1]: -1 moves the goal to the lane on "
                     "the left, +1 to the one on the right (NaN: none)")
