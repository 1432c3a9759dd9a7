"""Ground truth for soft manipulators: PCC model specs, symbolic equations of motion (CasADi),
generated C code, simulation and dataset files. Never imports jax.

Core API::

    from softpinn.symbolic import functions, TrueModel
    fns = functions("task4")          # dict of casadi.Function: M, M_inv, G, D, A, C, Cqd,
                                      # forward, inverse, energy, kinetic, potential,
                                      # momentum, hamiltonian, ode
    tm = TrueModel("task4")           # numpy face: tm.M(q), tm.qdd(q, qd, u), ... (batched)
"""

from softpinn.symbolic.derivation._eom import SymbolicModel, derive
from softpinn.errors import UserError
from softpinn.symbolic.model._functions import SIGNATURES, functions
from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.spec._spec import ModelSpec, Segment, SpecError, list_presets, load_spec

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
