"""letspi.metrics: surrogate safety and quality metrics of planned ego trajectories.

Entry points: ``compute_metrics`` (per scenario, vectorised over scenarios, neighbours and time),
``aggregate_metrics`` (paper Table III keys and extras) and ``render_markdown_table``. Every
per-scenario metric is declared once in ``letspi.metrics.registry``; one computation per module;
geometry conventions in ``letspi.metrics.inputs``.
"""

from letspi.metrics.aggregate import (
    DETAIL_COLUMNS,
    TABLE_COLUMNS,
    aggregate_metrics,
    finite_mean,
    recorded_config,
    render_markdown_table,
)
from letspi.metrics.compute import ScenarioMetrics, compute_metrics, human_future
from letspi.metrics.config import MetricsConfig
from letspi.metrics.inputs import MetricInputs
from letspi.metrics.registry import METRICS, Agg, Metric, reference_markdown
from letspi.metrics.relative import classify_offset, relative_position

__all__ = [
    "DETAIL_COLUMNS",
    "METRICS",
    "TABLE_COLUMNS",
    "Agg",
    "Metric",
    "MetricInputs",
    "MetricsConfig",
    "ScenarioMetrics",
    "aggregate_metrics",
    "classify_offset",
    "compute_metrics",
    "finite_mean",
    "human_future",
    "recorded_config",
    "reference_markdown",
    "relative_position",
    "render_markdown_table",
]
