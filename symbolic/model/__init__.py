"""A model's functions (order: spec -> derivation -> codegen -> model -> simulation -> recorded):
the derived equations wrapped as named CasADi Functions (M, G, D, A, forward, inverse,
energies, ode, ...) and :class:`TrueModel`, their batched numpy face, compiled where a compiler
exists. Imports :mod:`.spec`, :mod:`.derivation` and :mod:`.codegen`. Its modules are private;
the public names are re-exported by :mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
