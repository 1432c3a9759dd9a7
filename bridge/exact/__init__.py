"""The exact model in JAX: CasADi's symbolic ground truth (``softpinn.symbolic``) replayed as
pure ``jax.numpy`` functions, for batched and differentiable evaluation, RK4 simulation of
thousands of trajectories at once and known-actuator / hybrid models in ``softpinn.learn``.

    from softpinn.bridge.exact import jax_model
    em = jax_model("task5")                    # ExactModel: em.M(q), em.qdd(q, qd, u), ...
    qdd = jax.jit(jax.vmap(em.qdd))(Q, QD, U)  # batched forward dynamics (eq. 4)
"""

from softpinn.bridge.exact.dataset import make_dataset
from softpinn.bridge.exact.errors import TranslationError
from softpinn.bridge.exact.model import ExactModel, dynamics, jax_model
from softpinn.bridge.exact.simulate import simulate
from softpinn.bridge.exact.translate import Program, translate

__all__ = [
    "ExactModel",
    "Program",
    "TranslationError",
    "dynamics",
    "jax_model",
    "make_dataset",
    "simulate",
    "translate",
]
