"""Pictures and reports: trajectory and time-space diagrams, LLM panels, the HTML evaluation report.

Public entry points (Matplotlib figures are built with ``matplotlib.figure.Figure`` directly, so no
pyplot global state is touched and any backend works; PNG output uses Agg):

* ``plot_scenario`` (``letspi.viz.figure``): the paper's Figs 4-5 composition for one scenario.
* ``write_report`` (``letspi.viz.report``): a self-contained HTML report of an evaluation directory.
* ``IterationRecord`` (``letspi.viz.llm_panel``): one reflection iteration, as the panels show it.
"""

from letspi.viz.figure import plot_scenario
from letspi.viz.llm_panel import IterationRecord
from letspi.viz.report import write_report

__all__ = ["IterationRecord", "plot_scenario", "write_report"]
