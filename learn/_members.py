"""An ensemble's K members held as ONE stacked model (leading axis K): stacking and unstacking,
the per-member choice of new or old values, ``vmap`` over the member axis, and where the members
train (``vmap`` together or one after the other).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def select_members(mask, new, old):
    """Per-member choice on stacked pytrees: ``new`` where mask[k], else ``old``."""

    def pick(a, b):
        if a is None:
            return None
        m = mask.reshape(mask.shape + (1,) * (a.ndim - 1))
        return jnp.where(m, a, b)

    return jax.tree.map(pick, new, old)


def over_members(fn, in_axes):
    """``vmap(fn, in_axes)`` over the member axis, except for a single member, which is
    squeezed out and put back: on CPU a vmapped (batched) matmul of batch 1 ran twice as slow as
    the plain one (benchmarks/bench_train.py), and a vmapped line-search loop compiles twice as
    long."""
    vf = jax.vmap(fn, in_axes=in_axes)

    def call(*args):
        sizes = {
            jax.tree.leaves(a)[0].shape[0] for a, ax in zip(args, in_axes, strict=True) if ax == 0
        }
        if sizes != {1}:
            return vf(*args)
        first = lambda t: jax.tree.map(lambda a: a[0], t)
        out = fn(*(first(a) if ax == 0 else a for a, ax in zip(args, in_axes, strict=True)))
        return jax.tree.map(lambda a: a[None], out)

    return call


def stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def unstack(tree, k):
    return jax.tree.map(lambda x: x[k], tree)


def resolve_ensemble_mode(mode: str, seeds: int) -> str:
    """ "auto" -> "vmap" on an accelerator, "sequential" on CPU (vmap measured slower there)."""
    if seeds == 1:
        return "sequential"
    if mode != "auto":
        return mode
    return "sequential" if jax.default_backend() == "cpu" else "vmap"
