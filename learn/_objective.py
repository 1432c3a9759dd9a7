"""What one training step minimises and how: the loss the config selects (eq. 8/9, eq. 10 or a
rollout, plus the equilibrium label terms), its per-pair terms for evaluation, the pairs and
windows as JAX arrays, the optimizer (AdamW with the configured schedule), the stages of a
rollout schedule (:func:`rollout_stage`) and the box a training rollout must stay in
(:func:`training_box`). The jitted programs that use them are :mod:`learn._programs`'.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
import optax

from softpinn.errors import UserError
from softpinn.learn._baseline_errors import range_box
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
    rollout_loss_and_range,
)


def to_windows(w: WindowData, dtype) -> Windows:
    return Windows(*(jnp.asarray(a, dtype) for a in w))


def to_pairs(p: PairData, dtype) -> Pairs:
    a = lambda x: None if x is None else jnp.asarray(x, dtype)
    return Pairs(a(p.x0), a(p.u0), a(p.u1), a(p.dt), a(p.x1), a(p.xdot0))


def _configured(config: TrainConfig, accel: Callable, rollout: Callable, pair: Callable,
                horizon: int | None = None):
    """The one of ``accel``, ``rollout``, ``pair`` that ``config.loss`` names, with its options
    (``horizon``: the rollout's steps, default ``config.rollout_steps``)."""
    if config.loss == "accel":
        return lambda model, pairs: accel(model, pairs, config.accel_space,
                                          config.accel_weights)
    kw = dict(weight=config.loss_weight, substeps=config.substeps, input_hold=config.input_hold)
    if config.loss == "rollout":
        h = config.rollout_steps if horizon is None else horizon
        return lambda model, windows: rollout(model, windows, horizon=h, **kw)
    return lambda model, pairs: pair(model, pairs, **kw)


def loss_function(config: TrainConfig, labels: Equilibria | None = None,
                  horizon: int | None = None) -> Callable:
    """``loss(model, pairs) -> scalar`` of the configured kind (eq. 8/9, eq. 10 or rollout over
    ``horizon`` steps, default ``config.rollout_steps``), plus the equilibrium label terms
    (:func:`learn._losses.label_loss`) when ``labels`` are given and
    ``config.equilibrium_weight`` or ``config.force_weight`` is > 0."""
    base = _configured(config, accel_loss, rollout_loss, pair_loss, horizon)
    return _with_labels(config, labels, base)


def _with_labels(config, labels, base):
    weights = dict(equilibrium_weight=config.equilibrium_weight,
                   force_weight=config.force_weight)
    if labels is None or not any(weights.values()):
        return base
    return lambda model, batch, *a: _plus(base(model, batch, *a),
                                          label_loss(model, labels, **weights))


def _plus(value, extra):
    if isinstance(value, tuple):  # (loss, out-of-range fraction)
        return value[0] + extra, value[1]
    return value + extra


def loss_and_range_function(config: TrainConfig, labels: Equilibria | None,
                            horizon: int) -> Callable:
    """``f(model, windows, box) -> (loss, fraction)`` of loss "rollout" over ``horizon`` steps:
    :func:`loss_function`'s value and the fraction of the windows whose rollout leaves ``box``
    (:func:`training_box`) or is not finite, from the same simulation."""
    kw = dict(weight=config.loss_weight, substeps=config.substeps, input_hold=config.input_hold)
    base = lambda model, windows, box: rollout_loss_and_range(model, windows, box,
                                                              horizon=horizon, **kw)
    return _with_labels(config, labels, base)


def rollout_stage(config: TrainConfig, epoch: int) -> int:
    """The rollout horizon (steps) AdamW epoch ``epoch`` (1, 2, ...) trains at: with
    ``config.rollout_schedule`` (H_1, ..., H_S), H_i for epochs floor(i E / S) + 1 to
    floor((i + 1) E / S) of E (i = 0, ..., S - 1; stages spread evenly over the epochs), else
    ``config.rollout_steps`` throughout. The held-out loss is always at the last horizon."""
    sched = config.rollout_schedule
    if not sched:
        return config.rollout_steps
    stage = min(len(sched) - 1, (max(epoch, 1) - 1) * len(sched) // max(config.epochs, 1))
    return sched[stage]


#: the default horizon (s) of the held-out windows of ``test_with`` "rollout"
TEST_HORIZON = 5.0


def resolve_test_steps(config: TrainConfig, data, held_ids) -> TrainConfig:
    """``config`` with ``test_steps`` set where ``test_with`` is "rollout" and it is None:
    :data:`TEST_HORIZON` seconds at the data's median sample step, at most the samples of the
    shortest held-out trajectory (``held_ids``: validation and test) less one."""
    if config.test_with != "rollout" or config.test_steps is not None:
        return config
    ids = [int(k) for k in np.asarray(held_ids).tolist()]
    if not ids:
        return config
    dt = float(np.median(np.diff(data.t[data.indices(ids[0])])))
    shortest = min(int(data.indices(k).size) for k in ids) - 1
    steps = max(1, min(int(round(TEST_HORIZON / dt)) if dt > 0 else shortest, shortest))
    return dataclasses.replace(config, test_steps=steps)


def check_rollout_schedule(config: TrainConfig, data, train_ids) -> None:
    """Refuse, in one line naming the flag, a ``rollout_schedule`` whose last horizon is longer
    than the shortest training trajectory (in steps: its samples less one)."""
    if not config.rollout_schedule:
        return
    steps = min(int(data.indices(int(k)).size) - 1 for k in np.asarray(train_ids).tolist())
    if config.rollout_schedule[-1] > steps:
        raise UserError(f"rollout_schedule (--rollout-schedule): the last horizon "
                        f"({config.rollout_schedule[-1]} steps) is longer than the shortest "
                        f"training trajectory ({steps} steps); end the schedule at {steps} or "
                        "less")


def training_box(windows_x, n: int):
    """(low, high) (n,) each: the range of q over the training windows (B, h + 1, 2n) widened
    on each side as the baselines' rollouts are judged (:func:`learn._baseline_errors.range_box`).
    Traceable: the training programs compute it from the windows they are given."""
    q = jnp.reshape(jnp.asarray(windows_x)[..., :n], (-1, n))
    return range_box(jnp.min(q, axis=0), jnp.max(q, axis=0), xp=jnp)


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
    loss, or eq. 8/9 whatever the training loss). Loss "rollout" is scored at
    ``config.rollout_steps``, the LAST horizon of a ``rollout_schedule``, whatever stage the
    training is in: held-out losses stay comparable across the stages, and the best epoch is
    not picked by a stage's shorter horizon."""
    if test and config.test_with == "pair" and config.loss != "pair":
        config = dataclasses.replace(config, loss="pair", accel_space="acceleration",
                                     accel_weights=None, accel_labels="recorded")
    if test and config.test_with == "rollout":  # q alone (λ = 0): predict's rollout error
        return _configured(dataclasses.replace(config, loss="rollout", loss_weight=0.0),
                           accel_errors, rollout_errors, pair_errors, config.test_steps)
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


def note_range(history: list[list[dict]], epoch: int, horizon, out_of_range) -> None:
    """Loss "rollout": the epoch's horizon and the fraction (per member, (K,)) of its training
    windows whose rollout left :func:`training_box` or was not finite, added to each member's
    history row of ``epoch`` if one was recorded (issue 43: said, never a silent number)."""
    if out_of_range is None:
        return
    out_of_range = np.asarray(out_of_range, dtype=float)
    for k, hist in enumerate(history):
        if hist and hist[-1]["epoch"] == epoch and "out_of_range" not in hist[-1]:
            hist[-1]["horizon"] = int(horizon)
            hist[-1]["out_of_range"] = float(out_of_range[k])


def range_metrics(hist: list[dict]) -> dict:
    """Loss "rollout": ``rollout_out_of_range`` (the last AdamW epoch's fraction of training
    windows whose rollout left the training data's range widened by half its width, or was not
    finite) and ``rollout_out_of_range_max`` (the largest over the run); {} otherwise."""
    rows = [r["out_of_range"] for r in hist if "out_of_range" in r]
    if not rows:
        return {}
    return {"rollout_out_of_range": rows[-1], "rollout_out_of_range_max": max(rows)}
