"""Pictures and reports: trajectory and time-space diagrams, LLM panels, the HTML evaluation report.

Public entry points (Matplotlib figures are built with ``matplotlib.figure.Figure`` directly, so no
pyplot global state is touched and any backend works; PNG output uses Agg):

* ``plot_scenario`` (``letspi.viz.figure``): the paper's Figs 4-5 composition for one scenario.
* ``write_report`` (``letspi.viz.report``): a self-contained HTML report of an evaluation directory.
* ``IterationRecord`` (``letspi.viz.llm_panel``): one reflection iteration, as the panels show it.

Imports are lazy so ``import letspi.viz`` does not load Matplotlib.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from letspi.viz.figure import plot_scenario
    from letspi.viz.llm_panel import IterationRecord
    from letspi.viz.report import write_report

__all__ = ["IterationRecord", "plot_scenario", "write_report"]


def __getattr__(name: str) -> Any:
    if name == "plot_scenario":
        from letspi.viz.figure import plot_scenario

        return plot_scenario
    if name == "IterationRecord":
        from letspi.viz.llm_panel import IterationRecord

        return IterationRecord
    if name == "write_report":
        from letspi.viz.report import write_report

        return write_report
    raise AttributeError(f"module 'letspi.viz' has no attribute {name!r}")
