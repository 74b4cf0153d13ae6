"""Versioned benchmark suites (``letspi benchmark list | show | run``): a suite pins everything that makes
a result; ``run`` caches its data, evaluates planners in each mode and writes the leaderboard."""
