"""JAX as the commands that train, predict, compare or export use it: in float64, the precision
of the paper's numbers."""

from __future__ import annotations

import jax


def enable_x64() -> None:
    jax.config.update("jax_enable_x64", True)
