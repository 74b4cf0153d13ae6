"""Surrogate safety and quality metrics of planned ego trajectories: ``compute_metrics`` (per scenario),
``aggregate_metrics`` (Table III keys) and ``render_markdown_table``; each metric declared once in ``registry``.
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
