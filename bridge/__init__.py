"""Where the symbolic ground truth meets the learned models: comparisons, studies, reports,
deployment and the command line. The layers, from the bottom (``docs/architecture.md``):

    base ─► exact ─► analysis ─► figures ─► export ─► control ─► tasks ─► challenges, sweep
         ─► report ─► app ─► cli

A layer imports only the layers below it (``tests/test_layering.py``). Nothing here is imported
by :mod:`softpinn.symbolic` or :mod:`softpinn.learn`; this package is the only one that imports
both, and only through their faces.

The entry points resolve lazily (PEP 562), so that importing one layer does not import the
layers above it.
"""

from __future__ import annotations

import importlib

#: name -> module that defines it
_LAZY = {
    "analyze": "softpinn.bridge.analysis",
    "ReproduceConfig": "softpinn.bridge.tasks",
    "ReproduceResult": "softpinn.bridge.app",
    "make_plan": "softpinn.bridge.tasks",
    "reproduce": "softpinn.bridge.app",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'softpinn.bridge' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
