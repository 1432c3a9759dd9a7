"""XLA's fast-compile settings for short jobs, where compiling costs more than running.

A quick run (``softpinn reproduce --quick``, the test suite) trains tiny networks for a few
epochs: nearly all of its time is XLA compiling the training, prediction and analysis programs
(4-17 s each for a structured Lagrangian network on a 2-core machine). XLA's CPU backend
compiles them about twice as fast without LLVM's optimisation passes and its newer fusion
emitters, and the programs compute the same numbers to rounding (no fast-math is involved: at
optimisation level 0 quick task 5's float64 results agreed to 1e-15, with both flags the README's
quick task 3 printed the same digits; tests/test_xlaflags.py checks a program); they only run
slower, which a short job does not notice. Long runs keep XLA's defaults.

XLA reads ``XLA_FLAGS`` once, when JAX creates its backend (the first array): the flags must be
set before that, which :func:`use_fast_compile` checks.
"""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping

#: The flags, each with the setting it gives.
FAST_COMPILE = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")


def with_fast_compile(flags: str | None) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with :data:`FAST_COMPILE` added; a flag the user
    already set (to any value) is kept as the user set it."""
    words = (flags or "").split()
    given = {w.split("=", 1)[0] for w in words}
    words += [f for f in FAST_COMPILE if f.split("=", 1)[0] not in given]
    return " ".join(words)


def use_fast_compile(environ: MutableMapping[str, str] | None = None) -> bool:
    """Add :data:`FAST_COMPILE` to ``XLA_FLAGS`` in ``environ`` (default: this process's);
    returns False, changing nothing, when JAX's backend already exists in this process (XLA
    has read its flags then)."""
    if environ is None:
        environ = os.environ
        if _backend_started():
            return False
    environ["XLA_FLAGS"] = with_fast_compile(environ.get("XLA_FLAGS"))
    return True


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:  # only where this process imported JAX already (its flags are set before that)
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - a JAX without this module: assume started
        return True
    started = getattr(xla_bridge, "backends_are_initialized", None)
    return True if started is None else bool(started())
