"""letspi.analysis: what the data says a planner could gain (``letspi analyze``)."""
