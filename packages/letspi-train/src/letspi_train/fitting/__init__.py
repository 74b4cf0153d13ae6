"""Offline fitting of the classical planners' settings (``letspi fit sf``, ``letspi fit frenet``), each written
with its provenance to the file the planner table loads.
"""
