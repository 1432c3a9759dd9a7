"""What one training step minimises and how: the loss the config selects (eq. 8/9, eq. 10 or a
rollout, plus the equilibrium label terms), its per-pair terms for evaluation, the pairs and
windows as JAX arrays, and the optimizer (AdamW with the configured schedule). The jitted
programs that use them are :mod:`learn._programs`'.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
import optax

from softpinn.learn._config import TrainConfig
from softpinn.learn._data import PairData, WindowData
from softpinn.learn._losses import (
    Equilibria,
    Pairs,
    Windows,
    accel_errors,
    accel_loss,
    label_loss,
    pair_errors,
    pair_loss,
    rollout_errors,
    rollout_loss,
)


def to_windows(w: WindowData, dtype) -> Windows:
    return Windows(*(jnp.asarray(a, dtype) for a in w))


def to_pairs(p: PairData, dtype) -> Pairs:
    a = lambda x: None if x is None else jnp.asarray(x, dtype)
    return Pairs(a(p.x0), a(p.u0), a(p.u1), a(p.dt), a(p.x1), a(p.xdot0))


def _configured(config: TrainConfig, accel: Callable, rollout: Callable, pair: Callable):
    """The one of ``accel``, ``rollout``, ``pair`` that ``config.loss`` names, with its options."""
    if config.loss == "accel":
        return lambda model, pairs: accel(model, pairs, config.accel_space,
                                          config.accel_weights)
    kw = dict(weight=config.loss_weight, substeps=config.substeps, input_hold=config.input_hold)
    if config.loss == "rollout":
        return lambda model, windows: rollout(
            model, windows, horizon=config.rollout_steps, **kw
        )
    return lambda model, pairs: pair(model, pairs, **kw)


def loss_function(config: TrainConfig, labels: Equilibria | None = None) -> Callable:
    """``loss(model, pairs) -> scalar`` of the configured kind (eq. 8/9, eq. 10 or rollout),
    plus the equilibrium label terms (:func:`learn._losses.label_loss`) when ``labels`` are
    given and ``config.equilibrium_weight`` or ``config.force_weight`` is > 0."""
    base = _configured(config, accel_loss, rollout_loss, pair_loss)
    weights = dict(equilibrium_weight=config.equilibrium_weight,
                   force_weight=config.force_weight)
    if labels is None or not any(weights.values()):
        return base
    return lambda model, batch: base(model, batch) + label_loss(model, labels, **weights)


def labels_key(labels: Equilibria | None):
    """What identifies ``labels`` in :class:`ProgramCache`'s keys (they are constants of the
    compiled loss): None, or a digest of their values."""
    if labels is None:
        return None
    h = hashlib.sha256()
    for a in labels:
        a = np.asarray(a)
        h.update(str((a.shape, a.dtype)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def errors_function(config: TrainConfig, *, test: bool = False) -> Callable:
    """``errors(model, pairs) -> (B,)``: the per-pair terms whose mean is the loss; with
    ``test``, the terms held-out pairs are scored with (``config.test_with``: the training
    loss, or eq. 8/9 whatever the training loss)."""
    if test and config.test_with == "pair" and config.loss != "pair":
        config = dataclasses.replace(config, loss="pair", accel_space="acceleration",
                                     accel_weights=None, accel_labels="recorded")
    return _configured(config, accel_errors, rollout_errors, pair_errors)


def make_optimizer(
    config: TrainConfig, steps_per_epoch: int, *, peak: float | None = None
) -> optax.GradientTransformation:
    """AdamW with the configured warmup + decay schedule over ``epochs * steps_per_epoch``.

    ``peak`` overrides ``config.lr``; the training engine builds the schedule with peak 1 and
    multiplies the updates by the learning rate at run time (AdamW's update, weight decay
    included, is linear in the learning rate), so runs that differ only in ``lr`` share one
    compiled program.
    """
    total = max(1, config.epochs * steps_per_epoch)
    warm = int(config.warmup * total)
    lr = config.lr if peak is None else peak
    end = lr * config.lr_final
    if config.schedule == "cosine":
        sched = optax.warmup_cosine_decay_schedule(
            init_value=0.0 if warm else lr,
            peak_value=lr,
            warmup_steps=warm,
            decay_steps=total,
            end_value=end,
        )
    elif config.schedule == "exponential":
        sched = optax.warmup_exponential_decay_schedule(
            init_value=0.0 if warm else lr,
            peak_value=lr,
            warmup_steps=warm,
            transition_steps=max(1, total - warm),
            decay_rate=config.lr_final,
            end_value=end,
        )
    else:
        sched = optax.constant_schedule(lr)
    opt = optax.adamw(sched, weight_decay=config.weight_decay)
    if config.clip_norm > 0:
        opt = optax.chain(optax.clip_by_global_norm(config.clip_norm), opt)
    return opt
