"""Offline fitting of the classical planners' settings from recorded traffic.

``sf``: the fixed social force parameters (``letspi fit sf``); ``frenet``: the lattice's cost weights
(``letspi fit frenet``). Each writes a file with its provenance that the planner table loads.
"""
