"""The jitted programs of training: one whole epoch per call, evaluation, L-BFGS chunks, with
the optimizer and the loss the config selects, and an explicit cache of compiled programs
(:class:`ProgramCache`).

All K members of an ensemble are held as ONE stacked model (leading axis K) and every jitted
function is ``vmap``-ed over that axis; a single run is K = 1. One jitted call runs one whole
epoch: the minibatch permutation is drawn inside, and ``lax.scan`` steps through
``floor(N / B)`` minibatches of exactly B pairs (the remainder is dropped; it is a different
random remainder every epoch), so no shape ever changes and nothing recompiles. The
permutation key of epoch e is ``fold_in(PRNGKey(seed), e)``, which makes resumed runs identical
to uninterrupted ones.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from softpinn.learn._config import TrainConfig
from softpinn.learn._data import (
    PairData,
    WindowData,
)
from softpinn.errors import UserError
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
from softpinn.learn._models import make_model

# ----------------------------------------------------------------------------------- helpers


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
    import hashlib

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


def select_members(mask, new, old):
    """Per-member choice on stacked pytrees: ``new`` where mask[k], else ``old``."""

    def pick(a, b):
        if a is None:
            return None
        m = mask.reshape(mask.shape + (1,) * (a.ndim - 1))
        return jnp.where(m, a, b)

    return jax.tree.map(pick, new, old)


def _over_members(fn, in_axes):
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


def resolve_devices(devices: int) -> int:
    """The number of devices a run uses: ``devices``, or all there are for 0; refused with one
    line when more are asked for than there are."""
    have = jax.device_count()
    use = have if devices == 0 else devices
    if jax.process_count() > 1 and use != have:
        raise UserError(f"devices: training on {jax.process_count()} processes spans every "
                        f"process's devices ({have}); give --devices all")
    if use > have:
        hint = (" (on a CPU, XLA_FLAGS=--xla_force_host_platform_device_count=N before Python "
                "starts makes N devices)" if jax.default_backend() == "cpu" else "")
        raise UserError(f"devices: {use} asked for, {have} {jax.default_backend()} device(s) "
                        f"here{hint}")
    return use


def batch_sharding(devices: int):
    """How a minibatch is laid out over ``devices``: split along its first axis (data
    parallel); None for one device. The parameters stay replicated, and XLA reduces the
    gradients over the devices (no hand-written all-reduce)."""
    if devices <= 1:
        return None
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    mesh = Mesh(np.asarray(jax.devices()[:devices]), ("data",))
    return NamedSharding(mesh, PartitionSpec("data"))


def replicated(tree, devices: int):
    """``tree`` as global arrays replicated over the first ``devices`` devices of every process
    (each process holds the same values: the same data file and seed)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    mesh = Mesh(np.asarray(jax.devices()[:devices]), ("data",))
    rep = NamedSharding(mesh, PartitionSpec())

    def one(a):
        host = np.asarray(a)
        return jax.make_array_from_callback(host.shape, rep, lambda idx: host[idx])

    return jax.tree.map(one, tree)


def local_copy(tree):
    """This process's copy of replicated global arrays, as ordinary local arrays."""
    return jax.tree.map(lambda a: jnp.asarray(a.addressable_data(0)), tree)


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
        grad_fn = jax.value_and_grad(loss_params)

        sharding = batch_sharding(devices)

        def take(a, ix):
            b = a[ix]
            return b if sharding is None else jax.lax.with_sharding_constraint(b, sharding)

        def one_epoch(params, opt_state, key, epoch, lr, train):
            perm = jax.random.permutation(jax.random.fold_in(key, epoch), n_train)
            idx = perm[: self.steps * batch].reshape(self.steps, batch)

            def body(carry, ix):
                p, s = carry
                b = jax.tree.map(lambda a: take(a, ix), train)
                loss, g = grad_fn(p, b)
                updates, s = self.opt.update(g, s, p)
                p = optax.apply_updates(p, jax.tree.map(lambda u: lr * u, updates))
                return (p, s), loss

            (params, opt_state), losses = jax.lax.scan(body, (params, opt_state), idx)
            return params, opt_state, jnp.mean(losses)

        @jax.jit
        def epoch_fn(params, opt_state, keys, epoch, active, lr, train):
            new_p, new_s, loss = _over_members(one_epoch, (0, 0, 0, None, None, None))(
                params, opt_state, keys, epoch, lr, train
            )
            return (select_members(active, new_p, params),
                    select_members(active, new_s, opt_state), loss)

        self._epoch_fn = epoch_fn

        def weighted_sum_of(errors_of):
            def weighted_sum(params, chunk, w):
                return jnp.sum(w * errors_of(eqx.combine(params, static), chunk))

            return jax.jit(_over_members(weighted_sum, (0, None, None)))

        self._eval_chunk = weighted_sum_of(errors_function(config))
        self._eval_test_chunk = (weighted_sum_of(errors_function(config, test=True))
                                 if config.test_with == "pair" else self._eval_chunk)
        self.eval_size = max(batch, 256)
        self._set_eval_data(train, test)
        self.init_opt = jax.jit(_over_members(self.opt.init, (0,)))

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
            new_p, new_s, v = _over_members(lbfgs_chunk, (0, 0, None))(params, state, train)
            return select_members(active, new_p, params), select_members(active, new_s, state), v

        self._lbfgs_fn = lbfgs_fn

        def lbfgs_init(params):
            # optax.lbfgs's initial state holds weakly typed scalars (its line search's info)
            # where lbfgs_fn returns strong ones: without this, the second chunk's call did not
            # match the first's and compiled lbfgs_fn again (16-28 s on task 4, every run)
            state = _over_members(lbfgs.init, (0,))(params)
            return jax.tree.map(lambda a: jax.lax.convert_element_type(a, a.dtype), state)

        self.lbfgs_init = jax.jit(lbfgs_init)

    def with_data(self, config, train, test) -> Programs:
        """The same compiled functions for other arrays of the same shapes."""
        new = object.__new__(Programs)
        new.__dict__.update(self.__dict__)
        new.config, new.train, new.test = config, train, test
        new._global_train = None
        new._set_eval_data(train, test)
        return new

    def epoch_fn(self, params, opt_state, keys, epoch, active):
        lr = jnp.asarray(self.config.lr, jax.tree.leaves(self.train)[0].dtype)
        args = (params, opt_state, keys, epoch, active, lr)
        if self.devices > 1 and jax.process_count() > 1:
            # several processes (hosts): the jitted epoch spans every process's devices and
            # takes global arrays, replicated; its results come back as this process's copy,
            # so that the rest of the engine (checkpoints, losses) works on local arrays
            if getattr(self, "_global_train", None) is None:
                self._global_train = replicated(self.train, self.devices)
            out = self._epoch_fn(*replicated(args, self.devices), self._global_train)
            return local_copy(out)
        return self._epoch_fn(*args, self.train)

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
