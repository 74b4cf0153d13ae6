"""The LetsPi method (paper §III-C to §III-E), independent of any LLM backend."""

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
