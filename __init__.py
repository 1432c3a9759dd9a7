"""softpinn: learn dynamic models of soft robot manipulators with physics-inspired neural
networks, and check what they learned against exact equations of motion.

The repository root is this package; its three subpackages keep their folders:

- ``softpinn.symbolic`` (``symbolic/``, CasADi, never jax): specs, PCC kinematics, energies,
  equations of motion (eqs. 4, 7, 13-24), generated C, simulation, dataset files;
- ``softpinn.learn`` (``learn/``, JAX/Equinox/optax, never casadi): networks (eqs. 6-7), losses
  (eqs. 8-10), training, run directories, prediction;
- ``softpinn.bridge`` (``bridge/``, both): analyses of learned against true matrices, reports,
  the paper's task pipelines and the ``softpinn`` command line.

The first entry points are importable from here, lazily, so ``import softpinn`` stays cheap and
never pulls jax and casadi in together unless asked::

    import softpinn
    softpinn.TrueModel("task1").qdd(q, qd, u)          # exact model (symbolic)
    softpinn.train("data.npz", config, "runs/lnn")     # a network (learn)
    softpinn.reproduce(softpinn.ReproduceConfig("task1", quick=True), "out")
"""

from __future__ import annotations

import importlib

from softpinn._version import __version__

#: name -> module that defines it; resolved on first access (PEP 562).
_LAZY = {
    "TrueModel": "softpinn.symbolic",
    "load_spec": "softpinn.symbolic",
    "functions": "softpinn.symbolic",
    "list_presets": "softpinn.symbolic",
    "ModelConfig": "softpinn.learn",
    "TrainConfig": "softpinn.learn",
    "train": "softpinn.learn",
    "load_run": "softpinn.learn",
    "load_dataset": "softpinn.learn",
    "predict": "softpinn.learn",
    "ReproduceConfig": "softpinn.bridge",
    "reproduce": "softpinn.bridge",
    "analyze": "softpinn.bridge",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'softpinn' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
