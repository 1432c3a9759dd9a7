"""The equations of motion as CasADi expressions (above :mod:`.spec` in the order spec ->
derivation -> codegen -> model -> simulation -> recorded): PCC kinematics, energies and the
terms derived from them, the Euler-Lagrange parts of a :class:`SymbolicModel` and the backbone
shape; expressions in, expressions out, no file I/O and no compiled code. Imports only
:mod:`.spec`. Its modules are private; the public names are re-exported by
:mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
