"""Ground truth for soft manipulators: PCC model specs, symbolic equations of motion (CasADi),
generated C code, simulation and dataset files. Never imports jax.

Core API::

    from softpinn.symbolic import functions, TrueModel
    fns = functions("task4")          # dict of casadi.Function: M, M_inv, G, D, A, C, Cqd,
                                      # forward, inverse, energy, kinetic, potential,
                                      # momentum, hamiltonian, ode
    tm = TrueModel("task4")           # numpy face: tm.M(q), tm.qdd(q, qd, u), ... (batched)
"""

from .eom import SymbolicModel, derive
from .errors import UserError
from .functions import SIGNATURES, functions
from .model import TrueModel
from .spec import ModelSpec, Segment, SpecError, list_presets, load_spec

__all__ = [
    "SIGNATURES",
    "ModelSpec",
    "Segment",
    "SpecError",
    "SymbolicModel",
    "TrueModel",
    "UserError",
    "derive",
    "functions",
    "list_presets",
    "load_spec",
]
