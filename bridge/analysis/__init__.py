"""What the networks learned, against the true model: matrices at any q
(:mod:`.matrices`), the transforms P(q) with M ≈ P M̂ (:mod:`.transforms`, Tables I, II,
V-IX), force terms and accelerations along the data (:mod:`.forces`), linearised time scales
(:mod:`.modes`), one-step floors (:mod:`.floors`), and :func:`analyze`, which runs them all for
one trained run (:mod:`.compare`), and the files it writes (:mod:`.writer`)."""

from softpinn.bridge.analysis.compare import (
    AnalysisResult,
    analysis_q,
    analyze,
    learned_matrices,
    sample_q,
    true_matrices,
)
from softpinn.bridge.report.analysis import summary_numbers, write_report

__all__ = [
    "AnalysisResult",
    "analysis_q",
    "analyze",
    "learned_matrices",
    "sample_q",
    "summary_numbers",
    "true_matrices",
    "write_report",
]
