"""Training of the dynamics models: AdamW with a learning-rate schedule, minibatches of fixed
shape, jitted epochs, early stopping, seeded ensembles, checkpoints, resume, L-BFGS finish.

The losses are the one-step Runge-Kutta losses of eqs. 8 (velocity state) and 9 (momentum
state), or the acceleration loss of eq. 10, from :mod:`learn.losses`; the optimizer is AdamW
(Section III-B, "Model training"), via optax.

Engine. All K members of an ensemble are held as ONE stacked model (leading axis K) and every
jitted function is ``vmap``-ed over that axis; a single run is K = 1, and the "sequential"
ensemble mode runs the K = 1 engine once per seed with the same compiled functions. So an
ensemble member gives the same parameters as a single run with its seed, in either mode. One
jitted call runs one whole epoch: the minibatch permutation is drawn inside, and ``lax.scan``
steps through ``floor(N / B)`` minibatches of exactly B pairs (the remainder is dropped; it is
a different random remainder every epoch), so no shape ever changes and nothing recompiles.
The permutation key of epoch e is ``fold_in(PRNGKey(seed), e)``, which makes resumed runs
identical to uninterrupted ones.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import checkpoint as ckpt
from .data import (
    ACCEL_LABELS,
    Dataset,
    PairData,
    WindowData,
    load_dataset,
    make_pairs,
    make_windows,
    split_trajectories,
)
from .errors import UserError
from .losses import (
    Pairs,
    Windows,
    accel_errors,
    accel_loss,
    pair_errors,
    pair_loss,
    rollout_errors,
    rollout_loss,
)
from .models import ModelConfig, make_model

FORMAT = "softpinn-run"
FORMAT_VERSION = 1
SCHEDULES = ("cosine", "exponential", "constant")
LOSSES = ("pair", "accel", "rollout")
ENSEMBLE_MODES = ("auto", "vmap", "sequential")


class TrainingDiverged(UserError):
    """The loss became NaN or inf; the last good checkpoint is kept."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (with the dataset and the seed).

    ``model``: the network (:class:`learn.models.ModelConfig`; its n, m must match the data).
    ``epochs``: passes over the training pairs in minibatches of ``batch_size`` (clipped to the
    number of pairs; the remainder of each shuffled epoch is dropped so shapes never change).
    ``lr``: peak AdamW learning rate; ``schedule``: "cosine" (linear warmup over ``warmup`` of
    all steps, then cosine decay to ``lr * lr_final``), "exponential" (warmup, then exponential
    decay to ``lr * lr_final`` at the last step) or "constant"; ``weight_decay`` of AdamW;
    ``clip_norm`` > 0 clips the global gradient norm.
    ``loss``: "pair" (eq. 8/9 with weight λ = ``loss_weight``, ``substeps`` RK4 steps per pair,
    ``input_hold`` "constant" or "linear"), "accel" (eq. 10; velocity data only; q̈ labels as
    ``accel_labels`` says: "recorded" in the file or "differences" of the velocities) or "rollout"
    (the multi-step loss: eq. 8/9 averaged over ``rollout_steps`` RK4 steps simulated from the
    first state of windows of consecutive samples of one trajectory; minibatches of windows).
    ``seed``: first seed; ``seeds``: ensemble size K (seeds seed, seed+1, ...);
    ``ensemble``: "vmap", "sequential" or "auto" (vmap on an accelerator, sequential on CPU,
    where vmapping was measured slower; see benchmarks/bench_train.py).
    ``test_trajectories``: ids (tuple), a count (int), a fraction (float) or None (20%);
    ``split_seed`` draws the split and the ``samples`` subset of training pairs (None: all).
    ``patience``: stop a member after that many evaluations without a better test loss (None:
    never); the saved model is the one with the best test loss. ``eval_every``: epochs between
    test-loss evaluations. ``checkpoint_every``: epochs between checkpoints.
    ``lbfgs_steps``: L-BFGS iterations on the full training set after AdamW (0: none), starting
    from the best AdamW parameters, in calls of ``lbfgs_chunk`` iterations.
    """

    model: ModelConfig
    epochs: int = 1000
    batch_size: int = 1024
    lr: float = 1e-3
    schedule: str = "cosine"
    warmup: float = 0.02
    lr_final: float = 0.01
    weight_decay: float = 1e-4
    clip_norm: float = 0.0
    loss: str = "pair"
    loss_weight: float = 1.0
    rollout_steps: int = 5
    substeps: int = 1
    input_hold: str = "constant"
    accel_labels: str = "recorded"
    seed: int = 0
    seeds: int = 1
    ensemble: str = "auto"
    test_trajectories: tuple[int, ...] | int | float | None = None
    split_seed: int = 0
    samples: int | None = None
    patience: int | None = None
    eval_every: int = 1
    checkpoint_every: int = 25
    lbfgs_steps: int = 0
    lbfgs_chunk: int = 10

    def __post_init__(self):
        if not isinstance(self.model, ModelConfig):
            raise UserError(f"TrainConfig.model must be a ModelConfig, got {type(self.model)}")
        pos_int = (
            "epochs",
            "batch_size",
            "substeps",
            "seeds",
            "eval_every",
            "checkpoint_every",
            "rollout_steps",
        )
        for name in pos_int + ("lbfgs_chunk",):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise UserError(f"--{name.replace('_', '-')} must be an integer >= 1, got {v!r}")
        for name in ("lbfgs_steps", "seed", "split_seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise UserError(f"--{name.replace('_', '-')} must be an integer >= 0, got {v!r}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise UserError(f"--lr must be a positive number, got {self.lr!r}")
        if not 0 <= self.warmup < 1:
            raise UserError(f"warmup must be a fraction in [0, 1), got {self.warmup!r}")
        if not 0 < self.lr_final <= 1:
            raise UserError(f"lr_final must be in (0, 1], got {self.lr_final!r}")
        if self.weight_decay < 0 or self.clip_norm < 0 or self.loss_weight < 0:
            raise UserError("weight_decay, clip_norm and loss_weight must be >= 0")
        for name, allowed in (
            ("schedule", SCHEDULES),
            ("loss", LOSSES),
            ("ensemble", ENSEMBLE_MODES),
            ("input_hold", ("constant", "linear")),
            ("accel_labels", ACCEL_LABELS),
        ):
            if getattr(self, name) not in allowed:
                raise UserError(
                    f"--{name.replace('_', '-')} must be one of {list(allowed)}, "
                    f"got {getattr(self, name)!r}"
                )
        if self.patience is not None and (not isinstance(self.patience, int) or self.patience < 1):
            raise UserError(f"--patience must be an integer >= 1, got {self.patience!r}")
        if self.samples is not None and (not isinstance(self.samples, int) or self.samples < 1):
            raise UserError(f"--samples must be an integer >= 1, got {self.samples!r}")
        if isinstance(self.test_trajectories, list):
            object.__setattr__(self, "test_trajectories", tuple(self.test_trajectories))
        if self.accel_labels != "recorded" and self.loss != "accel":
            raise UserError(
                f"--accel-labels {self.accel_labels} is for --loss accel, not --loss {self.loss}"
            )
        if self.loss == "accel" and self.model.state_kind != "velocity":
            raise UserError(
                "--loss accel (eq. 10) needs velocity-state data (q̈ is stored, ṗ is not); "
                f"a {self.model.kind} model uses the {self.model.state_kind} state"
            )

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["model"] = self.model.to_dict()
        if isinstance(d["test_trajectories"], tuple):
            d["test_trajectories"] = list(d["test_trajectories"])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise UserError(f"unknown train config key(s) {unknown}")
        kw = dict(d)
        kw["model"] = ModelConfig.from_dict(d["model"])
        if isinstance(kw.get("test_trajectories"), list):
            kw["test_trajectories"] = tuple(kw["test_trajectories"])
        return cls(**kw)


@dataclass
class MemberResult:
    """The outcome of one seed: its run directory, best model and figures."""

    seed: int
    run_dir: Path
    model: Any
    metrics: dict
    history: list[dict] = field(repr=False)


@dataclass
class TrainResult:
    """What :func:`train` returns: the members and the aggregate metrics (mean ± std)."""

    run_dir: Path
    config: TrainConfig
    members: list[MemberResult]
    metrics: dict

    @property
    def model(self):
        """The best member's model (lowest best test loss)."""
        return min(self.members, key=lambda r: r.metrics["best_test_loss"]).model


# ----------------------------------------------------------------------------------- helpers


def _to_windows(w: WindowData, dtype) -> Windows:
    return Windows(*(jnp.asarray(a, dtype) for a in w))


def _to_pairs(p: PairData, dtype) -> Pairs:
    a = lambda x: None if x is None else jnp.asarray(x, dtype)
    return Pairs(a(p.x0), a(p.u0), a(p.u1), a(p.dt), a(p.x1), a(p.xdot0))


def _configured(config: TrainConfig, accel: Callable, rollout: Callable, pair: Callable):
    """The one of ``accel``, ``rollout``, ``pair`` that ``config.loss`` names, with its options."""
    if config.loss == "accel":
        return lambda model, pairs: accel(model, pairs)
    kw = dict(weight=config.loss_weight, substeps=config.substeps, input_hold=config.input_hold)
    if config.loss == "rollout":
        return lambda model, windows: rollout(
            model, windows, horizon=config.rollout_steps, **kw
        )
    return lambda model, pairs: pair(model, pairs, **kw)


def loss_function(config: TrainConfig) -> Callable:
    """``loss(model, pairs) -> scalar`` of the configured kind (eq. 8/9, eq. 10 or rollout)."""
    return _configured(config, accel_loss, rollout_loss, pair_loss)


def errors_function(config: TrainConfig) -> Callable:
    """``errors(model, pairs) -> (B,)``: the per-pair terms whose mean is the loss."""
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


def _select(mask, new, old):
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


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _unstack(tree, k):
    return jax.tree.map(lambda x: x[k], tree)


def resolve_ensemble_mode(mode: str, seeds: int) -> str:
    """ "auto" -> "vmap" on an accelerator, "sequential" on CPU (vmap measured slower there)."""
    if seeds == 1:
        return "sequential"
    if mode != "auto":
        return mode
    return "sequential" if jax.default_backend() == "cpu" else "vmap"


class _Programs:
    """The jitted functions of one run, built once and shared by all groups of members."""

    def __init__(self, config, static, train, test, n_train, batch):
        self.config = config
        self.static = static
        self.train = train
        self.test = test
        self.n_train = n_train
        self.batch = batch
        self.steps = n_train // batch
        self.opt = make_optimizer(config, self.steps, peak=1.0)
        loss_of = loss_function(config)

        def loss_params(params, batch_pairs):
            return loss_of(eqx.combine(params, static), batch_pairs)

        self._loss_params = loss_params
        grad_fn = jax.value_and_grad(loss_params)

        def one_epoch(params, opt_state, key, epoch, lr, train):
            perm = jax.random.permutation(jax.random.fold_in(key, epoch), n_train)
            idx = perm[: self.steps * batch].reshape(self.steps, batch)

            def body(carry, ix):
                p, s = carry
                b = jax.tree.map(lambda a: a[ix], train)
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
            return _select(active, new_p, params), _select(active, new_s, opt_state), loss

        self._epoch_fn = epoch_fn
        errors_of = errors_function(config)

        def weighted_sum(params, chunk, w):
            return jnp.sum(w * errors_of(eqx.combine(params, static), chunk))

        self._eval_chunk = jax.jit(_over_members(weighted_sum, (0, None, None)))
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
            return _select(active, new_p, params), _select(active, new_s, state), v

        self._lbfgs_fn = lbfgs_fn
        self.lbfgs_init = jax.jit(_over_members(lbfgs.init, (0,)))

    def with_data(self, config, train, test) -> _Programs:
        """The same compiled functions for other arrays of the same shapes."""
        new = object.__new__(_Programs)
        new.__dict__.update(self.__dict__)
        new.config, new.train, new.test = config, train, test
        new._set_eval_data(train, test)
        return new

    def epoch_fn(self, params, opt_state, keys, epoch, active):
        lr = jnp.asarray(self.config.lr, jax.tree.leaves(self.train)[0].dtype)
        return self._epoch_fn(params, opt_state, keys, epoch, active, lr, self.train)

    def _set_eval_data(self, train, test):
        self._train_chunks = _chunked(train, self.eval_size)
        self._test_chunks = _chunked(test, self.eval_size)
        self._n_eval = (jax.tree.leaves(train)[0].shape[0], jax.tree.leaves(test)[0].shape[0])

    def _evaluate(self, params, chunks, count):
        total = sum(self._eval_chunk(params, c, w) for c, w in zip(*chunks, strict=True))
        return total / count

    def eval_fn(self, params):
        """Mean loss of every member on the test pairs, (K,)."""
        return self._evaluate(params, self._test_chunks, self._n_eval[1])

    def eval_train_fn(self, params):
        """Mean loss of every member on all training pairs, (K,)."""
        return self._evaluate(params, self._train_chunks, self._n_eval[0])

    def lbfgs_fn(self, params, state, active):
        return self._lbfgs_fn(params, state, active, self.train)


#: Compiled programs by everything that shapes them, so that repeated runs in one process
#: (ensemble members, resumes, tests) do not recompile (4-17 s each for structured models).
_PROGRAM_CACHE: dict[tuple, _Programs] = {}
_PROGRAM_CACHE_SIZE = 8
#: TrainConfig fields that do not enter the compiled functions.
_UNCOMPILED = (
    "seed",
    "seeds",
    "lr",
    "ensemble",
    "test_trajectories",
    "split_seed",
    "samples",
    "patience",
    "eval_every",
    "checkpoint_every",
    "lbfgs_steps",
)


def _programs(config, train_pairs, test_pairs, n_train, batch) -> _Programs:
    shapes = tuple(
        None if a is None else (a.shape, str(a.dtype)) for a in (*train_pairs, *test_pairs)
    )
    fields = tuple(
        (f.name, repr(getattr(config, f.name)))
        for f in dataclasses.fields(config)
        if f.name not in _UNCOMPILED
    )
    key = (fields, shapes, n_train, batch)
    prog = _PROGRAM_CACHE.get(key)
    if prog is None:
        template = make_model(config.model, key=jax.random.PRNGKey(0))
        static = eqx.partition(template, eqx.is_array)[1]
        prog = _Programs(config, static, train_pairs, test_pairs, n_train, batch)
        if len(_PROGRAM_CACHE) >= _PROGRAM_CACHE_SIZE:
            _PROGRAM_CACHE.pop(next(iter(_PROGRAM_CACHE)))
        _PROGRAM_CACHE[key] = prog
    else:
        prog = prog.with_data(config, train_pairs, test_pairs)
    return prog


# ------------------------------------------------------------------------------ run layout


def _dataset_info(data: Dataset) -> dict:
    return {
        "path": data.path,
        "sha256": data.sha256,
        "n": data.n,
        "m": data.m,
        "name": data.meta.get("spec", {}).get("name") if isinstance(data.meta, dict) else None,
    }


def _member_dir(run_dir: Path, seed: int, k_total: int) -> Path:
    return run_dir if k_total == 1 else run_dir / f"{ckpt.MEMBER_PREFIX}{seed}"


def _mean_std(values) -> dict:
    v = np.asarray(values, dtype=float)
    return {"mean": float(v.mean()), "std": float(v.std())}


# ---------------------------------------------------------------------------------- engine


class _DeferredInterrupt:
    """While training, the first Ctrl-C (SIGINT) lets the current epoch finish, then the loop
    saves a checkpoint and raises KeyboardInterrupt; a second one interrupts at once. Only in the
    main thread (elsewhere signal handlers cannot be set, and Ctrl-C raises as usual)."""

    def __init__(self):
        self.requested = False
        self._old = None

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            try:
                self._old = signal.signal(signal.SIGINT, self._handler)
            except (ValueError, OSError):
                self._old = None
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


class _Group:
    """K members trained together as one stacked model (K = 1 for a single run)."""

    def __init__(self, prog: _Programs, seeds, ckpt_path: Path, header_base: dict):
        self.prog = prog
        self.seeds = list(seeds)
        self.K = len(self.seeds)
        self.ckpt_path = ckpt_path
        self.header_base = header_base
        cfg = prog.config
        models = [make_model(cfg.model, key=jax.random.PRNGKey(s)) for s in self.seeds]
        self.params = _stack([eqx.filter(m, eqx.is_array) for m in models])
        self.opt_state = prog.init_opt(self.params)
        self.best = self.params
        self.keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(s), 1) for s in self.seeds])
        self.epoch = 0  # epochs completed
        self.best_loss = np.full(self.K, np.inf)
        self.best_epoch = np.zeros(self.K, dtype=int)
        self.bad = np.zeros(self.K, dtype=int)
        self.active = np.ones(self.K, dtype=bool)
        self.stopped = ["running"] * self.K
        self.history: list[list[dict]] = [[] for _ in range(self.K)]
        self.seconds = 0.0
        self.adam_done = False
        self.lbfgs_done = 0

    # -- checkpoint
    def _tree(self):
        return (self.params, self.opt_state, self.best)

    def header(self) -> dict:
        return {
            **self.header_base,
            "seeds": self.seeds,
            "epoch": self.epoch,
            "best_loss": [float(x) for x in self.best_loss],
            "best_epoch": self.best_epoch.tolist(),
            "bad": self.bad.tolist(),
            "active": self.active.tolist(),
            "stopped": self.stopped,
            "history": self.history,
            "seconds": self.seconds,
            "adam_done": self.adam_done,
            "lbfgs_done": self.lbfgs_done,
        }

    def save(self):
        ckpt.save_tree(self.ckpt_path, self._tree(), self.header())

    def restore(self):
        header, tree = ckpt.load_tree(self.ckpt_path, self._tree())
        if header.get("seeds") != self.seeds:
            raise UserError(
                f"{self.ckpt_path}: checkpoint holds seeds {header.get('seeds')}, "
                f"expected {self.seeds}"
            )
        self.params, self.opt_state, self.best = tree
        self.epoch = int(header["epoch"])
        self.best_loss = np.array(header["best_loss"], dtype=float)
        self.best_epoch = np.array(header["best_epoch"], dtype=int)
        self.bad = np.array(header["bad"], dtype=int)
        self.active = np.array(header["active"], dtype=bool)
        self.stopped = list(header["stopped"])
        self.history = header["history"]
        self.seconds = float(header["seconds"])
        self.adam_done = bool(header["adam_done"])
        self.lbfgs_done = int(header["lbfgs_done"])

    @property
    def finished(self) -> bool:
        return self.adam_done and self.lbfgs_done >= self.prog.config.lbfgs_steps

    # -- bookkeeping shared by both phases
    def _record(self, epoch, train_loss, test_loss, phase, evaluate, params_prev, opt_prev):
        """Update best/patience/history after a step; roll back diverged members."""
        cfg = self.prog.config
        was_active = self.active.copy()
        train_loss = np.asarray(train_loss, dtype=float)
        test_loss = np.asarray(test_loss, dtype=float) if evaluate else None
        bad_now = self.active & ~np.isfinite(train_loss)
        if test_loss is not None:
            bad_now |= self.active & ~np.isfinite(test_loss)
        if bad_now.any():
            mask = jnp.asarray(bad_now)
            self.params = _select(mask, params_prev, self.params)
            self.opt_state = _select(mask, opt_prev, self.opt_state)
            for k in np.flatnonzero(bad_now):
                self.stopped[k] = f"diverged at epoch {epoch} ({phase})"
            self.active = self.active & ~bad_now
        if test_loss is not None:
            improved = self.active & (test_loss < self.best_loss)
            if improved.any():
                self.best = _select(jnp.asarray(improved), self.params, self.best)
            self.best_loss = np.where(improved, test_loss, self.best_loss)
            self.best_epoch = np.where(improved, epoch, self.best_epoch)
            if phase == "adamw":
                self.bad = np.where(improved, 0, self.bad + self.active)
                if cfg.patience is not None:
                    out = self.active & (self.bad >= cfg.patience)
                    for k in np.flatnonzero(out):
                        self.stopped[k] = f"early stop at epoch {epoch} (patience {cfg.patience})"
                    self.active = self.active & ~out
        for k in range(self.K):
            if bad_now[k] or not was_active[k]:
                continue
            if test_loss is not None:
                self.history[k].append(
                    {
                        "epoch": int(epoch),
                        "train_loss": float(train_loss[k]),
                        "test_loss": float(test_loss[k]),
                        "seconds": round(self.seconds, 3),
                        "phase": phase,
                    }
                )
        return bad_now

    def run(self, progress: Callable | None, label: str):
        with _DeferredInterrupt() as stop:
            self._run(progress, label, stop)

    def _run(self, progress, label, stop):
        cfg = self.prog.config
        prog = self.prog
        t_last = time.perf_counter()
        self.consistent = True
        try:
            if self.epoch == 0 and not any(self.history):
                # epoch 0: the untrained model, on the full training and test sets
                tr0 = np.asarray(prog.eval_train_fn(self.params))
                te0 = np.asarray(prog.eval_fn(self.params))
                self._record(0, tr0, te0, "adamw", True, self.params, self.opt_state)
                if progress is not None:
                    progress(self._progress_info(label, 0, tr0, te0, "adamw"))
            while not self.adam_done and self.epoch < cfg.epochs and self.active.any():
                if stop.requested:
                    raise KeyboardInterrupt
                e = self.epoch + 1
                prev_p, prev_s = self.params, self.opt_state
                new_p, new_s, tr = prog.epoch_fn(
                    self.params, self.opt_state, self.keys, self.epoch, jnp.asarray(self.active)
                )
                evaluate = e % cfg.eval_every == 0 or e == cfg.epochs
                te = prog.eval_fn(new_p) if evaluate else None
                tr = np.asarray(tr)
                te = None if te is None else np.asarray(te)
                now = time.perf_counter()
                # commit the epoch: the state is inconsistent until epoch = e
                self.consistent = False
                self.seconds += now - t_last
                t_last = now
                self.params, self.opt_state = new_p, new_s
                bad_now = self._record(e, tr, te, "adamw", evaluate, prev_p, prev_s)
                self.epoch = e
                self.consistent = True
                if bad_now.any():
                    self.save()
                    raise TrainingDiverged(self._diverged_message())
                if progress is not None:
                    progress(self._progress_info(label, e, tr, te, "adamw"))
                if e % cfg.checkpoint_every == 0:
                    self.save()
            if not self.adam_done:
                for k in range(self.K):
                    if self.stopped[k] == "running":
                        self.stopped[k] = f"completed {self.epoch} epochs"
                self.adam_done = True
                self.save()
            if cfg.lbfgs_steps > self.lbfgs_done:
                self._run_lbfgs(progress, label, stop)
        except KeyboardInterrupt:
            # save the last completed epoch; a second Ctrl-C in the middle of committing one
            # leaves the previous checkpoint on disk
            if self.consistent:
                self.save()
            raise

    def _run_lbfgs(self, progress, label, stop):
        cfg, prog = self.prog.config, self.prog
        # an interrupted L-BFGS phase restarts from the best parameters so far
        self.history = [[r for r in h if r["phase"] != "lbfgs"] for h in self.history]
        # start from the best AdamW parameters of every member that did not diverge
        ok = np.array([not s.startswith("diverged") for s in self.stopped])
        self.params = self.best
        state = prog.lbfgs_init(self.params)
        active = ok.copy()
        t_last = time.perf_counter()
        done = 0
        while done < cfg.lbfgs_steps and active.any():
            if stop.requested:
                raise KeyboardInterrupt
            prev_p = self.params
            self.params, state, tr = prog.lbfgs_fn(self.params, state, jnp.asarray(active))
            done += cfg.lbfgs_chunk
            te = np.asarray(prog.eval_fn(self.params))
            tr = np.asarray(tr)
            now = time.perf_counter()
            self.seconds += now - t_last
            t_last = now
            self.active = active
            epoch = self.epoch + done // cfg.lbfgs_chunk
            bad_now = self._record(epoch, tr, te, "lbfgs", True, prev_p, prev_p)
            active = active & ~bad_now
            if progress is not None:
                progress(self._progress_info(label, epoch, tr, te, "lbfgs", lbfgs_done=done))
        self.active = np.zeros(self.K, dtype=bool)
        self.lbfgs_done = cfg.lbfgs_steps
        self.save()

    def _diverged_message(self) -> str:
        which = [
            f"seed {s}: {st}"
            for s, st in zip(self.seeds, self.stopped, strict=True)
            if st.startswith("diverged")
        ]
        return (
            f"training stopped: the loss became NaN/inf ({'; '.join(which)}); "
            f"the last good checkpoint is kept in {self.ckpt_path.parent}; "
            "try a smaller --lr or --float64"
        )

    def _progress_info(self, label, epoch, tr, te, phase, lbfgs_done=None):
        return {
            "label": label,
            "seeds": self.seeds,
            "epoch": int(epoch),
            "epochs": self.prog.config.epochs,
            "phase": phase,
            "lbfgs_steps": self.prog.config.lbfgs_steps,
            "lbfgs_done": lbfgs_done,
            "train_loss": [float(x) for x in tr],
            "test_loss": None if te is None else [float(x) for x in te],
            "best_test_loss": [float(x) for x in self.best_loss],
            "active": self.active.tolist(),
            "seconds": self.seconds,
        }

    def member_model(self, k: int):
        return eqx.combine(_unstack(self.best, k), self.prog.static)


# ---------------------------------------------------------------------------------- train


def train(
    data: Dataset | str | Path,
    config: TrainConfig | None,
    out_dir: str | Path,
    *,
    progress: Callable[[dict], None] | None = None,
    force: bool = False,
    resume: bool = False,
) -> TrainResult:
    """Train ``config.seeds`` models on ``data`` and write the run directory ``out_dir``.

    ``out_dir`` gets ``config.json``, ``model.eqx`` (the best parameters), ``checkpoint.eqx``
    (everything needed to resume), ``history.csv``, ``metrics.json`` and ``loss.png``; an
    ensemble gets one such folder ``seed-<s>/`` per member and aggregate files on top.
    ``resume=True`` continues the run in ``out_dir`` from its last checkpoint with its stored
    configuration (``config`` may be None; if given it must equal the stored one). An existing,
    non-empty ``out_dir`` is refused unless ``force`` or ``resume``. ``progress(info)`` is
    called after every epoch with a dict of losses (the CLI draws a progress bar from it).
    Raises :class:`TrainingDiverged` on a NaN/inf loss (the last good checkpoint is kept);
    on KeyboardInterrupt it saves a checkpoint and re-raises.
    """
    run_dir = ckpt.prepare_run_dir(out_dir, force=force, resume=resume)
    if resume:
        stored = ckpt.read_json(run_dir / "config.json")
        if stored.get("format") != FORMAT:
            raise UserError(f"{run_dir}/config.json: not a softpinn run directory")
        stored_cfg = TrainConfig.from_dict(stored["train"])
        if stored_cfg.seeds > 1 and "members" not in stored:
            # a member folder: resuming it alone would start a new K-member ensemble inside it
            raise UserError(
                f"--resume: {run_dir} holds one member (seed {stored.get('seed')}) of a "
                f"{stored_cfg.seeds}-member ensemble; resume the ensemble's directory "
                f"({run_dir.parent} if this folder was not moved): its members resume together"
            )
        if config is not None and config != stored_cfg:
            diff = [
                f.name
                for f in dataclasses.fields(TrainConfig)
                if getattr(config, f.name) != getattr(stored_cfg, f.name)
            ]
            raise UserError(
                f"--resume: the options differ from the stored run in {run_dir} ({', '.join(diff)})"
            )
        config = stored_cfg
    elif config is None:
        raise UserError("train: a TrainConfig is needed unless resuming")
    if not isinstance(data, Dataset):
        data = load_dataset(data, n=config.model.n, m=config.model.m)
    if data.n != config.model.n or data.m != config.model.m:
        raise UserError(
            f"dataset file {data.path}: model has n={config.model.n}, m={config.model.m}; "
            f"the file has n={data.n}, m={data.m}"
        )
    if resume and stored["dataset"]["sha256"] != data.sha256:
        raise UserError(
            f"--resume: {data.path} is not the dataset the run in {run_dir} was trained on "
            f"(sha256 differs from {stored['dataset']['path']})"
        )
    dtype = jnp.dtype(config.model.dtype)
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise UserError(
            "float64 training needs jax.config.update('jax_enable_x64', True) before any array "
            "is created (or use --float32)"
        )

    train_ids, test_ids = split_trajectories(
        data, test=config.test_trajectories, seed=config.split_seed
    )
    state = config.model.state_kind
    if config.loss == "rollout":
        h = config.rollout_steps
        train_np = make_windows(
            data, train_ids, horizon=h, state=state, samples=config.samples, seed=config.split_seed
        )
        test_np = make_windows(data, test_ids, horizon=h, state=state)
        train_pairs, test_pairs = _to_windows(train_np, dtype), _to_windows(test_np, dtype)
    else:
        accel = config.accel_labels
        train_np = make_pairs(
            data, train_ids, state=state, samples=config.samples, seed=config.split_seed,
            accel=accel,
        )
        test_np = make_pairs(data, test_ids, state=state, accel=accel)
        if config.loss != "accel":
            train_np = train_np._replace(xdot0=None)
            test_np = test_np._replace(xdot0=None)
        train_pairs, test_pairs = _to_pairs(train_np, dtype), _to_pairs(test_np, dtype)
    batch = min(config.batch_size, train_np.count)

    prog = _programs(config, train_pairs, test_pairs, train_np.count, batch)

    seeds = [config.seed + i for i in range(config.seeds)]
    mode = resolve_ensemble_mode(config.ensemble, config.seeds)
    K = len(seeds)
    base = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "train": config.to_dict(),
        "model": config.model.to_dict(),
        "dataset": _dataset_info(data),
        "split": {"train": train_ids.tolist(), "test": test_ids.tolist()},
        "pairs": {"train": train_np.count, "test": test_np.count, "batch": batch},
        "steps_per_epoch": prog.steps,
        "ensemble_mode": mode,
    }
    if not resume:
        top = dict(base)
        if K > 1:
            top["members"] = [f"{ckpt.MEMBER_PREFIX}{s}" for s in seeds]
            top["seeds"] = seeds
        else:
            top["seed"] = seeds[0]
        ckpt.atomic_write_json(run_dir / "config.json", top)
        for s in seeds if K > 1 else []:
            mdir = _member_dir(run_dir, s, K)
            mdir.mkdir(parents=True, exist_ok=True)
            ckpt.atomic_write_json(mdir / "config.json", {**base, "seed": s})

    groups = []
    if mode == "vmap":
        groups.append(_Group(prog, seeds, run_dir / "checkpoint.eqx", {"format": FORMAT}))
    else:
        for s in seeds:
            groups.append(
                _Group(prog, [s], _member_dir(run_dir, s, K) / "checkpoint.eqx", {"format": FORMAT})
            )

    members: list[MemberResult] = []
    for g in groups:
        if resume and g.ckpt_path.is_file():
            g.restore()
        label = ",".join(str(s) for s in g.seeds)
        if not g.finished:
            try:
                g.run(progress, label)
            except (KeyboardInterrupt, TrainingDiverged):
                # leave a loadable run: best model so far, history and metrics
                for k, s in enumerate(g.seeds):
                    _finish_member(g, k, s, run_dir, K, train_np.count, test_np.count)
                raise
        for k, s in enumerate(g.seeds):
            members.append(_finish_member(g, k, s, run_dir, K, train_np.count, test_np.count))

    metrics = _aggregate(members, mode, base)
    if K > 1:
        ckpt.atomic_write_json(run_dir / "metrics.json", metrics)
        ckpt.write_history(run_dir / "history.csv", _mean_history([m.history for m in members]))
        _loss_plot(run_dir, [m.history for m in members], [f"seed {m.seed}" for m in members])
    return TrainResult(run_dir=run_dir, config=config, members=members, metrics=metrics)


def _loss_plot(run_dir, histories, labels):
    from .plots import plot_loss_curves

    plot_loss_curves(histories, run_dir / "loss.png", labels=labels, title=str(run_dir.name))


def _finish_member(g: _Group, k, seed, run_dir, K, n_train, n_test) -> MemberResult:
    mdir = _member_dir(run_dir, seed, K)
    model = g.member_model(k)
    hist = g.history[k]
    last = hist[-1] if hist else {"train_loss": float("nan"), "test_loss": float("nan")}
    metrics = {
        "seed": seed,
        "best_test_loss": float(g.best_loss[k]),
        "best_epoch": int(g.best_epoch[k]),
        "final_train_loss": last["train_loss"],
        "final_test_loss": last["test_loss"],
        "epochs_run": int(g.epoch),
        "lbfgs_steps": int(g.lbfgs_done),
        "stopped": g.stopped[k],
        "seconds": round(g.seconds, 3),
        "train_pairs": n_train,
        "test_pairs": n_test,
    }
    ckpt.save_tree(mdir / "model.eqx", eqx.filter(model, eqx.is_array), {"seed": seed})
    ckpt.write_history(mdir / "history.csv", hist)
    ckpt.atomic_write_json(mdir / "metrics.json", metrics)
    _loss_plot(mdir, [hist], None)
    return MemberResult(seed=seed, run_dir=mdir, model=model, metrics=metrics, history=hist)


def _mean_history(histories):
    by_epoch: dict[int, list[dict]] = {}
    for h in histories:
        for r in h:
            by_epoch.setdefault(r["epoch"], []).append(r)
    rows = []
    for e in sorted(by_epoch):
        rs = by_epoch[e]
        rows.append(
            {
                "epoch": e,
                "train_loss": float(np.mean([r["train_loss"] for r in rs])),
                "test_loss": float(np.mean([r["test_loss"] for r in rs])),
                "seconds": max(r["seconds"] for r in rs),
                "phase": rs[0]["phase"],
            }
        )
    return rows


def _aggregate(members, mode, base) -> dict:
    best = [m.metrics["best_test_loss"] for m in members]
    return {
        "seeds": [m.seed for m in members],
        "ensemble_mode": mode,
        "best_test_loss": _mean_std(best),
        "final_train_loss": _mean_std([m.metrics["final_train_loss"] for m in members]),
        "seconds": _mean_std([m.metrics["seconds"] for m in members]),
        "best_member": members[int(np.argmin(best))].seed,
        "pairs": base["pairs"],
        "train_pairs": base["pairs"]["train"],
        "test_pairs": base["pairs"]["test"],
        "members": [m.metrics for m in members],
    }


# --------------------------------------------------------------------------------- loading


@dataclass
class LoadedRun:
    """A trained model read back from a run directory."""

    model: Any
    model_config: ModelConfig
    train_config: TrainConfig
    seed: int
    run_dir: Path
    info: dict  # the whole config.json (dataset path/hash, split, pairs, ...)


def load_run(run_dir: str | Path, *, member: int | None = None) -> LoadedRun:
    """Load the best model of a run directory (``model.eqx`` + ``config.json``).

    For an ensemble directory, ``member`` picks the seed; None picks the member with the lowest
    best test loss (from ``metrics.json``). A member folder ``RUN/seed-<s>`` loads directly.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"run directory {run_dir}: no such directory")
    info = ckpt.read_json(run_dir / "config.json")
    if info.get("format") != FORMAT:
        raise UserError(f"{run_dir}/config.json: not a softpinn run directory")
    if "members" in info:
        seeds = info["seeds"]
        if member is None:
            mpath = run_dir / "metrics.json"
            if mpath.is_file():
                member = ckpt.read_json(mpath)["best_member"]
            else:
                member = seeds[0]
        if member not in seeds:
            raise UserError(f"run {run_dir}: no member with seed {member} (seeds {seeds})")
        return load_run(run_dir / f"{ckpt.MEMBER_PREFIX}{member}")
    mcfg = ModelConfig.from_dict(info["model"])
    tcfg = TrainConfig.from_dict(info["train"])
    if mcfg.dtype == "float64" and not jax.config.jax_enable_x64:
        raise UserError(
            f"run {run_dir} holds a float64 model: call "
            "jax.config.update('jax_enable_x64', True) before loading it"
        )
    like = eqx.filter(make_model(mcfg, key=jax.random.PRNGKey(0)), eqx.is_array)
    path = run_dir / "model.eqx"
    if not path.is_file():
        raise UserError(f"run {run_dir}: no model.eqx yet (training not finished; --resume it)")
    _, params = ckpt.load_tree(path, like)
    static = eqx.partition(make_model(mcfg, key=jax.random.PRNGKey(0)), eqx.is_array)[1]
    return LoadedRun(
        model=eqx.combine(params, static),
        model_config=mcfg,
        train_config=tcfg,
        seed=int(info["seed"]),
        run_dir=run_dir,
        info=info,
    )


def load_ensemble(run_dir: str | Path) -> list[LoadedRun]:
    """All members of a run directory (a single run gives a list of one)."""
    run_dir = Path(run_dir)
    info = ckpt.read_json(run_dir / "config.json")
    if "members" not in info:
        return [load_run(run_dir)]
    return [load_run(run_dir, member=s) for s in info["seeds"]]
