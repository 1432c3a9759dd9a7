"""Compiled code (order: spec -> derivation -> codegen -> model -> simulation -> recorded): CasADi
Functions exported as C, compiled under a supervised compiler into the code cache and loaded
back, the derive output folder, and the batched C kernels generated from SX instruction lists.
It works on any ``casadi.Function`` and imports no other subpackage of symbolic (only the
package's output helpers). Its modules are private; the public names are re-exported by
:mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
