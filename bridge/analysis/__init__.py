"""What the networks learned, against the true model: matrices at any q
(:mod:`.matrices`), the transforms P(q) with M ≈ P M̂ (:mod:`.transforms`, Tables I, II,
V-IX), force terms and accelerations along the data (:mod:`.forces`), linearised time scales
(:mod:`.modes`), one-step floors (:mod:`.floors`), and :func:`analyze`, which runs them all for
one trained run (:mod:`.compare`). Nothing here writes files: the analysis's tables and
figures are :mod:`softpinn.bridge.figures.analysis`."""

from softpinn.bridge.analysis.compare import (
    AnalysisResult,
    analysis_q,
    analyze,
    learned_matrices,
    sample_q,
    true_matrices,
)

__all__ = [
    "AnalysisResult",
    "analysis_q",
    "analyze",
    "learned_matrices",
    "sample_q",
    "true_matrices",
]
