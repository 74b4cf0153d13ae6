"""letspi.metrics: surrogate safety and quality metrics of planned ego trajectories.

Entry points: ``compute_metrics`` (per scenario, vectorised over scenarios, neighbours and time),
``aggregate_metrics`` (paper Table III keys) and ``render_markdown_table``. One metric per module;
geometry conventions in ``letspi.metrics._common``.
"""

from letspi.metrics._common import MetricInputs
from letspi.metrics.aggregate import TABLE_COLUMNS, aggregate_metrics, finite_mean, render_markdown_table
from letspi.metrics.config import MetricsConfig
from letspi.metrics.evaluate import ScenarioMetrics, compute_metrics, human_future
from letspi.metrics.relative import classify_offset, relative_position

__all__ = [
    "TABLE_COLUMNS",
    "MetricInputs",
    "MetricsConfig",
    "ScenarioMetrics",
    "aggregate_metrics",
    "classify_offset",
    "compute_metrics",
    "finite_mean",
    "human_future",
    "relative_position",
    "render_markdown_table",
]
