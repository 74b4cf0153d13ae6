"""Pictures and reports: trajectory and time-space diagrams, LLM panels, the HTML evaluation report. Figures are
``matplotlib.figure.Figure`` objects (no pyplot state; PNG through Agg)."""

from letspi.viz.figure import plot_scenario
from letspi.viz.llm_panel import IterationRecord
from letspi.viz.report import write_report

__all__ = ["IterationRecord", "plot_scenario", "write_report"]
