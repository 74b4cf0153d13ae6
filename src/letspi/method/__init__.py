"""letspi.method: the LetsPi method itself (paper §III-C to §III-E), independent of any LLM backend.

* ``thresholds``: ``ReflectionThresholds`` (TTC 1.5 s, in-path gap / contact 2.0 m, optional PET, iterations).
* ``reflection``: ``safety_report`` (vectorised), ``SafetyReport.to_text``, ``simulate_proposal``, ``reflect``.
* ``memory``: ``MemoryBank`` on SQLite (WAL, unique per scenario and configuration), ``Experience``.
* ``matching``: scenario similarity with the paper's slip fixed, vectorised ``top_k``.
* ``bench``: ``bench_retrieval`` (top-k over 10k / 100k experiences).
"""

from letspi.method.matching import PAPER_WEIGHTS, similarities, top_k
from letspi.method.memory import Experience, MemoryBank, MemoryFeatures, MemorySubset
from letspi.method.reflection import (
    IterationRecord,
    Proposal,
    ReflectionContext,
    ReflectionResult,
    SafetyReport,
    SimulatedPlan,
    Violation,
    reflect,
    safety_report,
    simulate_proposal,
)
from letspi.method.thresholds import ReflectionThresholds

__all__ = [
    "PAPER_WEIGHTS",
    "Experience",
    "IterationRecord",
    "MemoryBank",
    "MemoryFeatures",
    "MemorySubset",
    "Proposal",
    "ReflectionContext",
    "ReflectionResult",
    "ReflectionThresholds",
    "SafetyReport",
    "SimulatedPlan",
    "Violation",
    "reflect",
    "safety_report",
    "similarities",
    "simulate_proposal",
    "top_k",
]
