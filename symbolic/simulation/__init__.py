"""Simulated data (order: spec -> derivation -> codegen -> model -> simulation -> recorded): input
signals, the integration of a model's forward dynamics (cvodes or fixed-step RK4, batched in C
kernels where compiled), the spec's ``[data]`` table and its physics defaults, static
equilibria, data sets drawn and written in the dataset format, and trajectories farmed out to
Ray. Imports the subpackages below it. Its modules are private; the public names are
re-exported by :mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
