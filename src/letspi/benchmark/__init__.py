"""Versioned benchmark suites: ``letspi benchmark list | show | run``.

A suite (``letspi.benchmark.suites``) pins everything that makes a result; ``run`` generates its data
(cached by content), evaluates planners in each of its modes and writes a leaderboard with intervals
and paired comparisons against a reference planner (``letspi.benchmark.leaderboard``).
"""
