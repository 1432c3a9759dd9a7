"""The jitted programs of training: one whole epoch per call, evaluation, L-BFGS chunks, with
the optimizer and the loss the config selects (:mod:`learn._objective`), and an explicit cache
of compiled programs (:class:`ProgramCache`).

All K members of an ensemble are held as ONE stacked model (leading axis K) and every jitted
function is ``vmap``-ed over that axis (:mod:`learn._members`); a single run is K = 1. One
jitted call runs one whole epoch: the minibatch permutation is drawn inside, and ``lax.scan``
steps through ``floor(N / B)`` minibatches of exactly B pairs (the remainder is dropped; it is a
different random remainder every epoch), so no shape ever changes and nothing recompiles. The
permutation key of epoch e is ``fold_in(PRNGKey(seed), e)``, which makes resumed runs identical
to uninterrupted ones. A ``rollout_schedule`` compiles one epoch program per horizon (the
horizon is static), each once, when its stage begins; with loss "rollout" an epoch also returns
the fraction of its windows whose rollout left the training data's range (issue 43).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from softpinn.learn._devices import batch_sharding, local_copy, replicated
from softpinn.learn._losses import Equilibria, Pairs
from softpinn.learn._members import over_members, select_members
from softpinn.learn._models import make_model
from softpinn.learn._objective import (
    errors_function,
    labels_key,
    loss_and_range_function,
    loss_function,
    make_optimizer,
    training_box,
)

#: windows per evaluation chunk where held-out data are scored by rollouts (test_with rollout)
ROLLOUT_EVAL_SIZE = 16


def _chunked(pairs: Pairs, size: int) -> tuple[list[Pairs], list[jax.Array]]:
    """Split ``pairs`` into chunks of exactly ``size`` (the last padded with copies of the
    first pairs, weight 0), so that one compiled evaluation serves every set."""
    first = jax.tree.leaves(pairs)[0]
    n = first.shape[0]
    pad = (-n) % size
    idx = np.concatenate([np.arange(n), np.arange(pad) % n])
    w = np.concatenate([np.ones(n), np.zeros(pad)])
    chunks, weights = [], []
    for c in range((n + pad) // size):
        sl = idx[c * size : (c + 1) * size]
        chunks.append(jax.tree.map(lambda a, sl=sl: a[sl], pairs))
        weights.append(jnp.asarray(w[c * size : (c + 1) * size], first.dtype))
    return chunks, weights


class Programs:
    """The jitted functions of one run, built once and shared by all groups of members."""

    def __init__(self, config, static, train, test, n_train, batch, devices: int = 1,
                 labels: Equilibria | None = None):
        self.config = config
        self.devices = devices
        self.static = static
        self.train = train
        self.test = test
        self.n_train = n_train
        self.batch = batch
        self.steps = n_train // batch
        self.opt = make_optimizer(config, self.steps, peak=1.0)
        loss_of = loss_function(config, labels)

        def loss_params(params, batch_pairs):
            return loss_of(eqx.combine(params, static), batch_pairs)

        self._loss_params = loss_params
        self._labels = labels
        self._epoch_fns: dict[int | None, object] = {}
        self.rollout = config.loss == "rollout"
        self._epoch_fn = self._epoch_program(config.rollout_steps if self.rollout else None)

        def weighted_sum_of(errors_of):
            def weighted_sum(params, chunk, w):
                return jnp.sum(w * errors_of(eqx.combine(params, static), chunk))

            return jax.jit(over_members(weighted_sum, (0, None, None)))

        self._eval_chunk = weighted_sum_of(errors_function(config))
        self._eval_test_chunk = (weighted_sum_of(errors_function(config, test=True))
                                 if config.test_with in ("pair", "rollout")
                                 else self._eval_chunk)
        # held-out windows of test_with "rollout" are long (seconds of steps): chunks of a
        # few, so that padding a short held-out set to a chunk costs little
        self.eval_size = ROLLOUT_EVAL_SIZE if config.test_with == "rollout" else max(batch, 256)
        self._set_eval_data(train, test)
        self.init_opt = jax.jit(over_members(self.opt.init, (0,)))

        # L-BFGS on the full training set (optax.lbfgs with its zoom line search).
        lbfgs = optax.lbfgs()

        def lbfgs_chunk(params, state, train):
            full_loss = lambda p: loss_params(p, train)
            vg = optax.value_and_grad_from_state(full_loss)

            def body(carry, _):
                p, s = carry
                value, g = vg(p, state=s)
                updates, s = lbfgs.update(g, s, p, value=value, grad=g, value_fn=full_loss)
                return (optax.apply_updates(p, updates), s), value

            (params, state), values = jax.lax.scan(
                body, (params, state), None, length=config.lbfgs_chunk
            )
            return params, state, values[-1]

        @jax.jit
        def lbfgs_fn(params, state, active, train):
            new_p, new_s, v = over_members(lbfgs_chunk, (0, 0, None))(params, state, train)
            return select_members(active, new_p, params), select_members(active, new_s, state), v

        self._lbfgs_fn = lbfgs_fn

        def lbfgs_init(params):
            # optax.lbfgs's initial state holds weakly typed scalars (its line search's info)
            # where lbfgs_fn returns strong ones: without this, the second chunk's call did not
            # match the first's and compiled lbfgs_fn again (16-28 s on task 4, every run)
            state = over_members(lbfgs.init, (0,))(params)
            return jax.tree.map(lambda a: jax.lax.convert_element_type(a, a.dtype), state)

        self.lbfgs_init = jax.jit(lbfgs_init)

    def _epoch_program(self, horizon: int | None):
        """The jitted epoch of the loss at ``horizon`` rollout steps (None: not loss "rollout"),
        compiled once per horizon a rollout schedule reaches (the horizon is static): returns
        (params, opt_state, mean loss (K,)), and with loss "rollout" also the mean fraction
        (K,) of the epoch's windows whose rollout left the training data's range or is not
        finite (:func:`learn._objective.training_box` of the training windows)."""
        if horizon in self._epoch_fns:
            return self._epoch_fns[horizon]
        config, static, batch, n_train = self.config, self.static, self.batch, self.n_train
        steps, opt, n = self.steps, self.opt, config.model.n
        if horizon is None:
            loss_of = loss_function(config, self._labels)
            grad_fn = jax.value_and_grad(lambda p, b, box: loss_of(eqx.combine(p, static), b))
        else:
            loss_of = loss_and_range_function(config, self._labels, horizon)
            grad_fn = jax.value_and_grad(
                lambda p, b, box: loss_of(eqx.combine(p, static), b, box), has_aux=True)
        sharding = batch_sharding(self.devices)

        def take(a, ix):
            b = a[ix]
            return b if sharding is None else jax.lax.with_sharding_constraint(b, sharding)

        def one_epoch(params, opt_state, key, epoch, lr, train):
            perm = jax.random.permutation(jax.random.fold_in(key, epoch), n_train)
            idx = perm[: steps * batch].reshape(steps, batch)
            box = None if horizon is None else training_box(train.x, n)

            def body(carry, ix):
                p, s = carry
                b = jax.tree.map(lambda a: take(a, ix), train)
                value, g = grad_fn(p, b, box)
                updates, s = opt.update(g, s, p)
                p = optax.apply_updates(p, jax.tree.map(lambda u: lr * u, updates))
                return (p, s), value

            (params, opt_state), values = jax.lax.scan(body, (params, opt_state), idx)
            return params, opt_state, jax.tree.map(jnp.mean, values)

        @jax.jit
        def epoch_fn(params, opt_state, keys, epoch, active, lr, train):
            new_p, new_s, value = over_members(one_epoch, (0, 0, 0, None, None, None))(
                params, opt_state, keys, epoch, lr, train
            )
            return (select_members(active, new_p, params),
                    select_members(active, new_s, opt_state), value)

        self._epoch_fns[horizon] = epoch_fn
        return epoch_fn

    def with_data(self, config, train, test) -> Programs:
        """The same compiled functions for other arrays of the same shapes."""
        new = object.__new__(Programs)
        new.__dict__.update(self.__dict__)
        new.config, new.train, new.test = config, train, test
        new._global_train = None
        new._set_eval_data(train, test)
        return new

    def epoch_fn(self, params, opt_state, keys, epoch, active):
        """One AdamW epoch at the run's horizon: (params, opt_state, mean loss (K,))."""
        return self.epoch_step(params, opt_state, keys, epoch, active)[:3]

    def epoch_step(self, params, opt_state, keys, epoch, active, horizon: int | None = None):
        """One AdamW epoch: (params, opt_state, mean loss (K,), out-of-range fraction (K,) of
        loss "rollout"'s windows, else None); ``horizon``: the rollout's steps this epoch
        (a stage of ``rollout_schedule``; default ``rollout_steps``)."""
        if self.rollout and horizon is None:
            horizon = self.config.rollout_steps
        fn = self._epoch_program(horizon if self.rollout else None)
        lr = jnp.asarray(self.config.lr, jax.tree.leaves(self.train)[0].dtype)
        args = (params, opt_state, keys, epoch, active, lr)
        if self.devices > 1 and jax.process_count() > 1:
            # several processes (hosts): the jitted epoch spans every process's devices and
            # takes global arrays, replicated; its results come back as this process's copy,
            # so that the rest of the engine (checkpoints, losses) works on local arrays
            if getattr(self, "_global_train", None) is None:
                self._global_train = replicated(self.train, self.devices)
            out = local_copy(fn(*replicated(args, self.devices), self._global_train))
        else:
            out = fn(*args, self.train)
        p, s, value = out
        return (p, s, *value) if self.rollout else (p, s, value, None)

    def _set_eval_data(self, train, test):
        self._train_chunks = _chunked(train, self.eval_size)
        self._test_chunks = _chunked(test, self.eval_size)
        self._n_eval = (jax.tree.leaves(train)[0].shape[0], jax.tree.leaves(test)[0].shape[0])

    def _evaluate(self, fn, params, chunks, count):
        total = sum(fn(params, c, w) for c, w in zip(*chunks, strict=True))
        return total / count

    def eval_fn(self, params):
        """Mean test loss of every member on the test pairs (``config.test_with``), (K,)."""
        return self._evaluate(self._eval_test_chunk, params, self._test_chunks, self._n_eval[1])

    def eval_train_fn(self, params):
        """Mean training loss of every member on all training pairs, (K,)."""
        return self._evaluate(self._eval_chunk, params, self._train_chunks, self._n_eval[0])

    def lbfgs_fn(self, params, state, active):
        return self._lbfgs_fn(params, state, active, self.train)



class ProgramCache:
    """Compiled programs by everything that shapes them, so that repeated runs in one process
    (ensemble members, resumes, tests) do not recompile (4-17 s each for structured models).
    Holds at most ``size`` programs, dropping the oldest. :func:`learn._train.train` takes one
    (``programs=``); :data:`PROGRAMS` is the process's default."""

    #: TrainConfig fields that do not enter the compiled functions.
    UNCOMPILED = (
        "seed",
        "seeds",
        "lr",
        "ensemble",
        "test_trajectories",
        "validation",
        "split_seed",
        "samples",
        "patience",
        "overfit",
        "overfit_evals",
        "target_loss",
        "eval_every",
        "checkpoint_every",
        "lbfgs_steps",
        "devices",  # the resolved count is part of the key
    )

    def __init__(self, size: int = 8):
        self.size = size
        self.entries: dict[tuple, Programs] = {}

    def get(self, config, train_pairs, test_pairs, n_train, batch, devices: int = 1,
            labels: Equilibria | None = None) -> Programs:
        """The programs for ``config`` and these pair shapes on ``devices`` devices (and the
        equilibrium ``labels`` of the training loss, if any): cached, or compiled now."""
        shapes = tuple(
            None if a is None else (a.shape, str(a.dtype)) for a in (*train_pairs, *test_pairs)
        )
        fields = tuple(
            (f.name, repr(getattr(config, f.name)))
            for f in dataclasses.fields(config)
            if f.name not in self.UNCOMPILED
        )
        key = (fields, shapes, n_train, batch, devices, labels_key(labels))
        prog = self.entries.get(key)
        if prog is None:
            template = make_model(config.model, key=jax.random.PRNGKey(0))
            static = eqx.partition(template, eqx.is_array)[1]
            prog = Programs(config, static, train_pairs, test_pairs, n_train, batch, devices,
                            labels)
            if len(self.entries) >= self.size:
                self.entries.pop(next(iter(self.entries)))
            self.entries[key] = prog
        else:
            prog = prog.with_data(config, train_pairs, test_pairs)
        return prog


#: the default cache of this process
PROGRAMS = ProgramCache()
