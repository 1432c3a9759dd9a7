"""Recorded data (order: spec -> derivation -> codegen -> model -> simulation -> recorded): CSV
recordings of a real arm read, filtered (smoothing, derivatives) and imported into the dataset
format, and the commented template spec ``softpinn init`` writes for an arm of one's own. It may
import every subpackage below it. Its modules are private; the public names are re-exported by
:mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
