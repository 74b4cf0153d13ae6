"""letspi.assembly: the one place that turns configurations into planners, LLM backends and LetsPi phases."""
