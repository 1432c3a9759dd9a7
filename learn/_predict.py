"""Evaluation of trained models: one-step test error and rollouts against the truth.

* One-step error: the per-pair loss of eq. 8 (velocity state) or eq. 9 (momentum state) on
  every test pair, reported as mean ± std over pairs (Table III's "Test error").
* Rollout error: simulate each test trajectory from its true initial state with its true inputs
  over ``horizon`` seconds; the error of a trajectory is the mean over its samples after t0 of
  ‖q - q̂‖² (the q part of eq. 8); reported as mean ± std over trajectories (Table III's
  "prediction error"). ``reset_every`` re-sets the state to the truth every S seconds
  (Figs. 15, 17). ``dt`` integrates with a step other than the data's (Figs. 24, 25): the inputs
  are interpolated linearly from the data onto the new grid, and the prediction is compared at
  the data times (exactly where the grids coincide, by linear interpolation elsewhere).

All trajectories are padded to one length (zero steps repeat the last state) so that one
compiled, vmapped rollout serves them all; long ones run in chunks of :data:`ROLLOUT_CHUNK`
steps, and one-step errors in chunks of :data:`PAIR_CHUNK` pairs, so that one compiled function
of each serves every length (the test and training pairs, the data's and another step's
rollouts: two compilations per model where there were four, 19 of 24 s of a task 5
network's predictions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from softpinn.errors import UserError
from softpinn.learn._data import Dataset, load_dataset, make_pairs, trajectories
from softpinn.learn._integrate import rollout
from softpinn.learn._losses import Pairs, pair_errors
from softpinn.learn._rundir import load_run
from softpinn.learn.plots import check_may_write, plot_rollout


@dataclass
class PredictResult:
    """Figures of one evaluation; :meth:`to_json` gives the ``predict --json`` object."""

    one_step_error: dict  # {"mean", "std", "pairs"}
    rollout_error_mean: float
    rollout_error_std: float
    rollout_errors: list[float]
    horizon: float
    reset_every: float | None
    dt: float | None
    trajectories: list[int]
    rollouts: list[dict] = field(repr=False)  # per trajectory: t, q_true, q_pred, resets
    plot: str | None = None
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """A strictly JSON-valid dict (non-finite numbers become null)."""
        clean = lambda x: float(x) if x is not None and math.isfinite(x) else None
        return {
            "one_step_error": {
                "mean": clean(self.one_step_error["mean"]),
                "std": clean(self.one_step_error["std"]),
                "pairs": self.one_step_error["pairs"],
            },
            "rollout_error_mean": clean(self.rollout_error_mean),
            "rollout_error_std": clean(self.rollout_error_std),
            "rollout_errors": [clean(e) for e in self.rollout_errors],
            "rollout_diverged": int(sum(not math.isfinite(e) for e in self.rollout_errors)),
            "horizon": self.horizon,
            "reset_every": self.reset_every,
            "dt": self.dt,
            "trajectories": self.trajectories,
            "plot": self.plot,
            **self.extra,
        }


#: The most memory the arrays of one batched rollout may take (``dt`` far below the data's
#: step multiplies the steps): checked before anything is allocated.
MAX_ROLLOUT_BYTES = 2 * 2**30


def _check_positive(name, value, *, allow_none=True):
    if value is None and allow_none:
        return None
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not math.isfinite(value) or value <= 0):
        raise UserError(f"{name}: expected a positive number of seconds, got {value!r}")
    return float(value)


def check_rollout_request(trajs: list[dict], *, horizon: float, dt: float | None,
                          n: int, m: int, itemsize: int) -> None:
    """Refuse, before any work, a rollout request that cannot mean what it says: a horizon
    longer than the longest trajectory (more than a sample step beyond it), a step longer
    than the horizon, or so many steps that the arrays would exceed :data:`MAX_ROLLOUT_BYTES`."""
    spans = [float(tr["t"][-1] - tr["t"][0]) for tr in trajs]
    step = max(float(np.max(np.diff(tr["t"]))) if tr["t"].size > 1 else 0.0 for tr in trajs)
    longest = max(spans)
    if horizon > longest + 1.5 * step + 1e-9:
        raise UserError(
            f"horizon: {horizon:g} s is longer than the trajectories ({longest:.6g} s at most, "
            f"sample step {step:.3g} s); give at most {longest:.6g}"
        )
    if dt is None:
        return
    if dt > horizon:
        raise UserError(f"dt: {dt:g} s is longer than the horizon ({horizon:g} s)")
    steps = math.ceil(min(horizon, longest) / dt) + 1
    need = len(trajs) * _bucket(steps) * (2 * (2 * n) + m + 1) * itemsize
    if need > MAX_ROLLOUT_BYTES:
        raise UserError(
            f"dt: {dt:g} s makes {steps:.3g} steps per trajectory for {len(trajs)} trajectories "
            f"(about {need / 2**30:.3g} GiB, the limit is {MAX_ROLLOUT_BYTES / 2**30:g} GiB); "
            f"use a larger dt (the data's step is {step:.3g} s)"
        )


_pair_errors_static = eqx.filter_jit(
    lambda model, pairs, weight, *, substeps, input_hold: pair_errors(
        model, pairs, weight=weight, substeps=substeps, input_hold=input_hold
    )
)


#: pairs per compiled call of :func:`one_step_errors` (more are evaluated in chunks of it)
PAIR_CHUNK = 4096
#: steps per compiled call of :func:`rollouts` (longer rollouts continue chunk by chunk)
ROLLOUT_CHUNK = 512


def _bucket(n: int) -> int:
    """Padded length: the next power of two (at least 16), so that calls with similar sizes
    share one compiled function."""
    return max(16, 1 << (int(n) - 1).bit_length())


def _chunked(n: int, chunk: int) -> int:
    """Padded length of ``n`` items evaluated ``chunk`` at a time: a power of two up to one
    chunk, whole chunks beyond."""
    return _bucket(n) if n <= chunk else -(-n // chunk) * chunk


def one_step_errors(
    model, pairs: Pairs, *, weight=1.0, substeps: int = 1, input_hold: str = "constant"
) -> np.ndarray:
    """Per-pair error of eq. 8/9 for every pair, as a numpy array (B,)."""
    n = pairs.x0.shape[0]
    total = _chunked(n, PAIR_CHUNK)
    size = min(total, PAIR_CHUNK)
    idx = np.arange(total) % n  # pad with copies of real pairs, dropped below
    out = []
    for start in range(0, total, size):
        part = jax.tree.map(lambda a, i=idx[start:start + size]: a[i], pairs)
        out.append(np.asarray(_pair_errors_static(model, part, weight, substeps=substeps,
                                                  input_hold=input_hold)))
    return np.concatenate(out)[:n]


@eqx.filter_jit
def _batched_rollout(model, x0, u, t, x_true, mask, *, substeps, input_hold):
    one = lambda a, b, c, d, e: rollout(
        model, a, b, c, substeps=substeps, input_hold=input_hold, reset=(d, e)
    )
    return jax.vmap(one)(x0, u, t, x_true, mask)


def _chunked_rollout(model, X, U, T, Mk, *, substeps, input_hold) -> np.ndarray:
    """The vmapped rollouts from ``X[:, 0]`` over ``T.shape[1] - 1`` steps, at most
    :data:`ROLLOUT_CHUNK` per compiled call (each chunk starts from the last state of the one
    before): (B, T, 2n)."""
    steps = T.shape[1] - 1
    size = min(steps, ROLLOUT_CHUNK)
    x = jnp.asarray(X[:, 0])
    parts = [np.asarray(x)[:, None]]
    for start in range(0, steps, size):
        window = slice(start, start + size + 1)
        traj = _batched_rollout(model, x, jnp.asarray(U[:, window]), jnp.asarray(T[:, window]),
                                jnp.asarray(X[:, window]), jnp.asarray(Mk[:, window]),
                                substeps=substeps, input_hold=input_hold)
        x = traj[:, -1]
        parts.append(np.asarray(traj[:, 1:]))
    return np.concatenate(parts, axis=1)


def _reset_mask(t: np.ndarray, t0: float, every: float | None) -> np.ndarray:
    """True at the first grid time at or after each t0 + j * every (j >= 1)."""
    mask = np.zeros(t.shape, dtype=bool)
    if every is None:
        return mask
    j = np.floor((t - t0) / every + 1e-9).astype(int)
    mask[1:] = j[1:] > j[:-1]
    return mask


def _interp_rows(tq, t, a):
    """Linear interpolation of the columns of ``a`` (T, k) from times ``t`` to ``tq``."""
    return np.stack([np.interp(tq, t, a[:, i]) for i in range(a.shape[1])], axis=1).reshape(
        len(tq), a.shape[1]
    )


def rollouts(
    model,
    trajs: list[dict],
    *,
    horizon: float,
    reset_every: float | None = None,
    dt: float | None = None,
    substeps: int = 1,
    input_hold: str = "constant",
) -> list[dict]:
    """Simulate every trajectory dict (from :func:`learn._data.trajectories`) over ``horizon``.

    Returns per trajectory ``t`` (the data times within the horizon), ``q_true``, ``q_pred``,
    ``error`` (mean over samples after t0 of ‖q - q̂‖²) and ``resets`` (reset times).
    """
    n = model.config.n
    dtype = np.dtype(model.config.dtype)
    check_rollout_request(trajs, horizon=horizon, dt=dt, n=n, m=model.config.m,
                          itemsize=dtype.itemsize)
    grids = []
    for tr in trajs:
        t, x, u = tr["t"], tr["x"], tr["u"]
        t0 = t[0]
        keep = t - t0 <= horizon * (1 + 1e-12) + 1e-12
        td, xd, ud = t[keep], x[keep], u[keep]
        if td.size < 2:
            raise UserError(
                f"horizon: {horizon} s is shorter than the first step of trajectory {tr['id']}"
            )
        if dt is None:
            tg, ug, xg = td, ud, xd
        else:
            steps = int(math.ceil((td[-1] - t0) / dt - 1e-9))
            tg = t0 + dt * np.arange(steps + 1)
            ug = _interp_rows(tg, td, ud) if ud.shape[1] else np.zeros((tg.size, 0))
            xg = _interp_rows(tg, td, xd)
        grids.append((tr["id"], td, xd, tg, ug, xg, _reset_mask(tg, t0, reset_every)))
    L = _chunked(max(g[3].size for g in grids) - 1, ROLLOUT_CHUNK) + 1  # steps + the start

    def pad(a, k):
        return np.concatenate([a, np.repeat(a[-1:], k, axis=0)], axis=0) if k else a

    T = np.stack([pad(g[3], L - g[3].size) for g in grids]).astype(dtype)
    U = np.stack([pad(g[4], L - g[3].size) for g in grids]).astype(dtype)
    X = np.stack([pad(g[5], L - g[3].size) for g in grids]).astype(dtype)
    Mk = np.stack([np.r_[g[6], np.zeros(L - g[6].size, bool)] for g in grids])
    pred = _chunked_rollout(model, X, U, T, Mk, substeps=substeps, input_hold=input_hold)
    out = []
    for i, (tid, td, xd, tg, _ug, _xg, mask) in enumerate(grids):
        qg = pred[i, : tg.size, :n]
        q_pred = qg if dt is None else _interp_rows(td, tg, qg)
        q_true = xd[:, :n]
        d = q_pred[1:] - q_true[1:]
        with np.errstate(over="ignore", invalid="ignore"):
            err = float(np.mean(np.sum(d * d, axis=1)))
        out.append(
            {
                "id": tid,
                "t": td,
                "q_true": q_true,
                "q_pred": q_pred,
                "error": err if math.isfinite(err) else float("inf"),
                "resets": tg[mask],
            }
        )
    return out


def evaluate(
    model,
    data: Dataset,
    traj_ids,
    *,
    horizon: float,
    reset_every: float | None = None,
    dt: float | None = None,
    loss_weight: float = 1.0,
    substeps: int = 1,
    input_hold: str = "constant",
    plot: str | Path | None = None,
    force: bool = False,
    label: str | None = None,
) -> PredictResult:
    """One-step and rollout errors of ``model`` on trajectories ``traj_ids`` of ``data``.

    ``plot``: a PNG to write; an existing file is overwritten only if softpinn wrote it (a
    plot of an earlier call) or ``force``; ``label`` names the model in its title (default:
    its kind)."""
    horizon = _check_positive("horizon", horizon, allow_none=False)
    if plot is not None:
        check_may_write(plot, force=force)
    reset_every = _check_positive("reset_every", reset_every)
    dt = _check_positive("dt", dt)
    cfg = model.config
    if data.n != cfg.n or data.m != cfg.m:
        raise UserError(
            f"dataset file {data.path}: the model has n={cfg.n}, m={cfg.m}; "
            f"the file has n={data.n}, m={data.m}"
        )
    ids = [int(i) for i in traj_ids]
    state = cfg.state_kind
    pnp = make_pairs(data, ids, state=state)
    dtype = jnp.dtype(cfg.dtype)
    pairs = Pairs(*(jnp.asarray(a, dtype) for a in pnp[:5]), None)
    errs = one_step_errors(
        model, pairs, weight=loss_weight, substeps=substeps, input_hold=input_hold
    )
    rolls = rollouts(
        model,
        trajectories(data, ids, state=state),
        horizon=horizon,
        reset_every=reset_every,
        dt=dt,
        substeps=substeps,
        input_hold=input_hold,
    )
    r = np.array([ro["error"] for ro in rolls])
    with np.errstate(invalid="ignore", over="ignore"):
        r_mean, r_std = float(np.mean(r)), float(np.std(r))
    plot_path = None
    if plot is not None:
        ro = rolls[0]
        what = f"{label or cfg.kind}: trajectory {ro['id']} of {Path(str(data.path)).name}, " \
               f"horizon {horizon:g} s"
        if reset_every:
            what += f", reset every {reset_every:g} s"
        if dt:
            what += f", dt {dt:g} s"
        spec = data.meta.get("spec") if isinstance(data.meta, dict) else None
        plot_path = str(plot_rollout(
            ro["t"], ro["q_true"], ro["q_pred"], plot, title=what, resets=ro["resets"],
            names=data.meta.get("coordinates") if isinstance(data.meta, dict) else None,
            kind=spec.get("kind") if isinstance(spec, dict) else None))
    return PredictResult(
        one_step_error={
            "mean": float(np.mean(errs)),
            "std": float(np.std(errs)),
            "pairs": int(errs.size),
        },
        rollout_error_mean=r_mean,
        rollout_error_std=r_std,
        rollout_errors=[float(x) for x in r],
        horizon=horizon,
        reset_every=reset_every,
        dt=dt,
        trajectories=ids,
        rollouts=rolls,
        plot=plot_path,
    )


def predict(
    run_dir: str | Path,
    data: Dataset | str | Path,
    *,
    horizon: float,
    reset_every: float | None = None,
    dt: float | None = None,
    trajectories: str | list[int] = "auto",
    member: int | None = None,
    plot: str | Path | None = None,
    force: bool = False,
) -> PredictResult:
    """Evaluate the model of a run directory on a dataset file.

    ``trajectories``: "auto" (the run's test trajectories when ``data`` is the file it was
    trained on, else every trajectory), "test", "all", or a list of ids. The one-step error uses
    the run's loss settings (λ, sub-steps, input hold). ``plot``/``force``: see :func:`evaluate`.
    """
    run = load_run(run_dir, member=member)
    cfg = run.model_config
    if not isinstance(data, Dataset):
        data = load_dataset(data, n=cfg.n, m=cfg.m)
    data = run.inputs(data)
    same = data.sha256 == run.info["dataset"]["sha256"]
    if trajectories == "auto":
        trajectories = "test" if same else "all"
    if trajectories == "test":
        if not same:
            raise UserError(
                f"dataset file {data.path} is not the one run {run.run_dir} was trained on, "
                "so it has no test split; use all trajectories"
            )
        ids = run.info["split"]["test"]
    elif trajectories == "all":
        ids = data.trajectory_ids.tolist()
    else:
        ids = [int(i) for i in trajectories]
        unknown = sorted(set(ids) - set(data.trajectory_ids.tolist()))
        if unknown:
            raise UserError(f"trajectories {unknown} are not in {data.path}")
    tc = run.train_config
    res = evaluate(
        run.model,
        data,
        ids,
        horizon=horizon,
        reset_every=reset_every,
        dt=dt,
        loss_weight=tc.loss_weight,
        substeps=tc.substeps,
        input_hold=tc.input_hold,
        plot=plot,
        force=force,
        label=f"{Path(run.run_dir).name} ({cfg.kind})",
    )
    res.extra = {
        "run": str(run.run_dir),
        "seed": run.seed,
        "model": cfg.kind,
        "dataset": data.path,
        "split": "test" if same and ids == run.info["split"]["test"] else "given",
    }
    return res
