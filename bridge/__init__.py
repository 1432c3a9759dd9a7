"""Where the symbolic ground truth meets the learned models.

Data flow (each box a subpackage; arrows are calls)::

    spec.toml ──► softpinn.symbolic ──► dataset.npz ──► softpinn.learn ──► run directory
      │ [training] recipe        (simulate)                 (train)              │
      ▼                                                                          ▼
    tasks/  plan ─► stages: data ─► train ─► predict ─► floor ─► modes ─► analyze ─► report/
                                                                    │
    analysis/  true (CasADi) and learned (JAX) M, D, G, A at the same q; transforms P(q);
               force terms and accelerations along the data; time scales; floors
    report/    paper-shaped tables, figures, report.md
    exact/     the CasADi functions replayed in JAX (jit, vmap, grad) and RK4 simulation
    export/    a trained network rebuilt in CasADi (Functions, generated C) for control
    cli/       the ``softpinn`` command line: flags onto these functions

Nothing here is imported by :mod:`softpinn.symbolic` or :mod:`softpinn.learn`; this package is
the only one that imports both.
"""

from softpinn.bridge.analysis import analyze
from softpinn.bridge.tasks import ReproduceConfig, ReproduceResult, make_plan, reproduce

__all__ = ["ReproduceConfig", "ReproduceResult", "analyze", "make_plan", "reproduce"]
