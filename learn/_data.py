"""Dataset files: loading, validation, train/test split by trajectory, and training pairs.

A dataset file (``.npz``, written by ``symbolic.simulation._datasets``) holds flat arrays over
all samples of all trajectories: ``t`` (T,), ``q``, ``qd``, ``qdd``, ``p`` (T, n), ``u`` (T, m),
``traj`` (T,) integer trajectory index, and ``meta``, a 0-d string of JSON; ``p`` may be left
out (a recording has no momenta). A training pair is two consecutive samples of ONE trajectory
(never across two); its step ``dt`` is read from ``t``, so variable-step data works. The pairs
feed the one-step losses of eqs. 8 and 9 (state (q, q̇) or (q, p)), and the acceleration loss of
eq. 10 (q̈ from the file).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from softpinn.errors import UserError
from softpinn.files import DATASET_EQUILIBRIUM, DATASET_OPTIONAL, DATASET_REQUIRED

#: Arrays every dataset file must hold (:mod:`softpinn.files`, the rule symbolic reads by too).
REQUIRED_KEYS = DATASET_REQUIRED
#: Arrays a dataset file may hold: the momenta p = M(q) q̇ (simulated data hold them; without
#: them a Hamiltonian network trains on the velocities, :mod:`learn._velocity`).
OPTIONAL_KEYS = DATASET_OPTIONAL
#: Optional arrays: static equilibria G(q*) = A(q*) u* (all three or none; docs/dataset.md), the
#: labels of ``TrainConfig.equilibrium_weight`` and ``force_weight``.
EQUILIBRIUM_KEYS = DATASET_EQUILIBRIUM
#: The two state layouts a model can ask for: (q, q̇) for Lagrangian and black-box models on
#: velocity data, (q, p) for Hamiltonian models (eq. 7).
STATE_KINDS = ("velocity", "momentum")


@dataclass(frozen=True, eq=False)
class Dataset:
    """A validated dataset file. Arrays are float64 (``traj`` int64), samples in file order."""

    path: str
    sha256: str
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    p: np.ndarray | None  # None: the file holds no momenta
    u: np.ndarray
    traj: np.ndarray
    meta: dict
    eq_q: np.ndarray | None = None  # (K, n) static equilibria, or None
    eq_u: np.ndarray | None = None  # (K, m) their constant inputs
    eq_force: np.ndarray | None = None  # (K, n) G(q*) = A(q*) u*

    @property
    def equilibria(self) -> int:
        """The number of static equilibria the file holds (0: none)."""
        return 0 if self.eq_q is None else int(self.eq_q.shape[0])

    @property
    def n(self) -> int:
        """Number of generalized coordinates."""
        return int(self.q.shape[1])

    @property
    def m(self) -> int:
        """Number of inputs."""
        return int(self.u.shape[1])

    @property
    def trajectory_ids(self) -> np.ndarray:
        """The distinct trajectory indices, sorted."""
        return np.unique(self.traj)

    def indices(self, traj_id: int) -> np.ndarray:
        """Sample indices of one trajectory, in time order."""
        return np.flatnonzero(self.traj == traj_id)

    def state(self, kind: str) -> np.ndarray:
        """The state of every sample: (q, q̇) for ``"velocity"``, (q, p) for ``"momentum"``."""
        if kind not in STATE_KINDS:
            raise UserError(f"state kind must be one of {STATE_KINDS}, got {kind!r}")
        if kind == "momentum" and self.p is None:
            raise UserError(f"dataset file {self.path} holds no momenta p: a Hamiltonian network "
                            "trains on it with --momenta velocity (learn/_velocity.py)")
        return np.concatenate([self.q, self.qd if kind == "velocity" else self.p], axis=1)

    def state_derivative(self, kind: str, accel: str = "recorded") -> np.ndarray | None:
        """d/dt of the state of every sample: (q̇, q̈) for velocity, (q̇, ṗ) for momentum.
        ``accel``: q̈ as ``"recorded"`` in the file, or estimated from the velocities by
        ``"differences"`` (:func:`difference_accelerations`). The file stores no ṗ: for
        momentum ``"differences"`` gives ṗ from the momenta (:func:`difference_momenta`) and
        ``"recorded"`` None (the acceleration loss refuses it with a message)."""
        if accel not in ACCEL_LABELS:
            raise UserError(f"accel labels must be one of {list(ACCEL_LABELS)}, got {accel!r}")
        if kind == "velocity":
            qdd = self.qdd if accel == "recorded" else difference_accelerations(self)
            return np.concatenate([self.qd, qdd], axis=1)
        if accel == "differences" and self.p is not None:
            return np.concatenate([self.qd, difference_momenta(self)], axis=1)
        return None


#: Where the q̈ labels of the acceleration loss (eq. 10) come from.
ACCEL_LABELS = ("recorded", "differences")


def _differences(data: Dataset, values: np.ndarray) -> np.ndarray:
    """d/dt of ``values`` (one row per sample) by second-order central differences over t
    within each trajectory (one-sided second order at its ends, first order for a trajectory
    of two samples)."""
    out = np.zeros_like(values)
    for tid in data.trajectory_ids.tolist():
        rows = data.indices(int(tid))
        if rows.size < 2:
            continue
        out[rows] = np.gradient(values[rows], data.t[rows], axis=0,
                                edge_order=2 if rows.size > 2 else 1)
    return out


def difference_accelerations(data: Dataset) -> np.ndarray:
    """q̈ estimated from the recorded velocities alone: second-order central differences of q̇
    over t within each trajectory (:func:`_differences`), as velocity-only measurements allow
    (the paper's remedy for coarse sampling, Section VI-A: "use the acceleration information
    directly as training labels"). The error is O(dt²): 0.3-0.5 % of rms q̈ on Task 5's
    100 Hz data, 1-2 % at 50 Hz.
    """
    return _differences(data, data.qd)


def difference_momenta(data: Dataset) -> np.ndarray:
    """ṗ estimated from the recorded momenta as :func:`difference_accelerations` estimates q̈
    from q̇: the labels of eq. 10 for a Hamiltonian network on momentum data, whose q̇ half,
    q̇ = ∂H/∂p = M⁻¹(q) p (eq. 7), is then fitted against the recorded q̇ at every sample."""
    if data.p is None:
        raise UserError(f"dataset file {data.path} holds no momenta p")
    return _differences(data, data.p)


def mass_scale(data: Dataset, kind: str, traj_ids=None) -> float:
    """A data-derived initial diagonal for the mass network (``ModelConfig.mass_init``).

    p = M q̇, so per coordinate rms(pᵢ) / rms(q̇ᵢ) is the scale of M's diagonal and its inverse
    that of M⁻¹'s; the median over coordinates for a "lagrangian" model (M) or a "hamiltonian"
    one (M⁻¹), over the given trajectories (None: all). 1.0 when the data cannot say (p or q̇
    identically zero).
    """
    if kind not in ("lagrangian", "lagrangian-hessian", "hamiltonian"):
        raise UserError(f"mass_scale: kind must be a physics model kind, got {kind!r}")
    if data.p is None:
        raise UserError(f"mass_init 'data': dataset file {data.path} holds no momenta p to take "
                        "the mass scale from; give a number")
    keep = slice(None) if traj_ids is None else np.isin(data.traj, np.asarray(traj_ids))
    rms_qd = np.sqrt(np.mean(data.qd[keep] ** 2, axis=0))
    rms_p = np.sqrt(np.mean(data.p[keep] ** 2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = rms_qd / rms_p if kind == "hamiltonian" else rms_p / rms_qd
    ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
    return float(np.median(ratio)) if ratio.size else 1.0


class PairData(NamedTuple):
    """Training pairs as numpy arrays; fields match ``learn._losses.Pairs``.

    x0, x1: (B, 2n) states at consecutive samples; u0, u1: (B, m) inputs there; dt: (B,) step;
    xdot0: (B, 2n) state derivative at x0 (for eq. 10) or None.
    """

    x0: np.ndarray
    u0: np.ndarray
    u1: np.ndarray
    dt: np.ndarray
    x1: np.ndarray
    xdot0: np.ndarray | None

    @property
    def count(self) -> int:
        return int(self.x0.shape[0])

    def take(self, idx: np.ndarray) -> PairData:
        """The pairs at ``idx``."""
        return PairData(
            self.x0[idx],
            self.u0[idx],
            self.u1[idx],
            self.dt[idx],
            self.x1[idx],
            None if self.xdot0 is None else self.xdot0[idx],
        )


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def load_dataset(path: str | Path, *, n: int | None = None, m: int | None = None) -> Dataset:
    """Read and validate a dataset file.

    Refuses, with a one-line :class:`UserError` naming the file and the problem: a missing file or
    key, arrays of mismatched shapes, NaN or inf, time that does not increase strictly within a
    trajectory, samples of one trajectory that are not contiguous, and a model size other than
    ``n`` coordinates / ``m`` inputs when these are given.
    """
    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise UserError(f"dataset file {name}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in REQUIRED_KEYS if k not in z.files]
            if missing:
                raise UserError(
                    f"dataset file {name}: missing key(s) {', '.join(missing)} "
                    f"(expected {', '.join(REQUIRED_KEYS)})"
                )
            arrays = {k: np.asarray(z[k]) for k in REQUIRED_KEYS + OPTIONAL_KEYS
                      if k in z.files}
            eq = {k: np.asarray(z[k]) for k in EQUILIBRIUM_KEYS if k in z.files}
    except UserError:
        raise
    except Exception as exc:  # not a zip / not an npz / object arrays
        raise UserError(f"dataset file {name}: cannot be read as .npz ({exc})") from None

    try:
        meta = json.loads(str(arrays["meta"].item()) if arrays["meta"].shape == () else "")
    except (json.JSONDecodeError, ValueError):
        raise UserError(f"dataset file {name}: 'meta' must be a 0-d string of JSON") from None
    if not isinstance(meta, dict):
        raise UserError(f"dataset file {name}: 'meta' must hold a JSON object")

    t, traj = arrays["t"], arrays["traj"]
    if t.ndim != 1:
        raise UserError(f"dataset file {name}: 't' must have shape (T,), got {t.shape}")
    T = t.shape[0]
    if T < 2:
        raise UserError(f"dataset file {name}: needs at least 2 samples, got {T}")
    if traj.shape != (T,):
        raise UserError(f"dataset file {name}: 'traj' must have shape ({T},), got {traj.shape}")
    if not np.issubdtype(traj.dtype, np.integer):
        raise UserError(f"dataset file {name}: 'traj' must be integer, got dtype {traj.dtype}")
    q = arrays["q"]
    if q.ndim != 2 or q.shape[0] != T or q.shape[1] < 1:
        raise UserError(f"dataset file {name}: 'q' must have shape ({T}, n), got {q.shape}")
    n_file = q.shape[1]
    for key in ("qd", "qdd", "p"):
        if key in arrays and arrays[key].shape != (T, n_file):
            raise UserError(
                f"dataset file {name}: '{key}' must have shape ({T}, {n_file}) like 'q', "
                f"got {arrays[key].shape}"
            )
    u = arrays["u"]
    if u.ndim != 2 or u.shape[0] != T:
        raise UserError(f"dataset file {name}: 'u' must have shape ({T}, m), got {u.shape}")
    for key in ("t", "q", "qd", "qdd", "p", "u"):
        if key not in arrays:
            continue
        a = arrays[key]
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise UserError(f"dataset file {name}: '{key}' must be numeric, got dtype {a.dtype}")
        bad = ~np.isfinite(a)
        if bad.any():
            first = np.argwhere(bad)[0]
            raise UserError(
                f"dataset file {name}: '{key}' holds {int(bad.sum())} NaN/inf value(s), "
                f"first at index {tuple(int(i) for i in first)}"
            )
    if n is not None and n_file != n:
        raise UserError(
            f"dataset file {name}: model has n={n} coordinates, the file has n={n_file}"
        )
    if m is not None and u.shape[1] != m:
        raise UserError(f"dataset file {name}: model has m={m} inputs, the file has m={u.shape[1]}")

    # Trajectories must be contiguous runs with strictly increasing time.
    starts = np.flatnonzero(np.r_[True, traj[1:] != traj[:-1]])
    if len(starts) != len(np.unique(traj)):
        raise UserError(
            f"dataset file {name}: samples of a trajectory must be contiguous in 'traj'"
        )
    same = traj[1:] == traj[:-1]
    dt = np.diff(t.astype(np.float64))
    bad = same & ~(dt > 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise UserError(
            f"dataset file {name}: time must increase within a trajectory, but in trajectory "
            f"{int(traj[i])} t[{i + 1}]={t[i + 1]!r} <= t[{i}]={t[i]!r}"
        )
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
    eq = _equilibria(name, eq, n_file, u.shape[1])
    return Dataset(
        path=str(path.resolve()),
        sha256=file_sha256(path),
        t=f64(t),
        q=f64(q),
        qd=f64(arrays["qd"]),
        qdd=f64(arrays["qdd"]),
        p=f64(arrays["p"]) if "p" in arrays else None,
        u=f64(u),
        traj=traj.astype(np.int64),
        meta=meta,
        **eq,
    )


def _equilibria(name: str, eq: dict, n: int, m: int) -> dict:
    """The optional equilibrium arrays of a file, checked (all three or none, (K, n), (K, m),
    (K, n), finite), as float64."""
    if not eq:
        return {}
    if len(eq) != len(EQUILIBRIUM_KEYS):
        raise UserError(f"dataset file {name}: has {', '.join(eq)} but not "
                        f"{', '.join(k for k in EQUILIBRIUM_KEYS if k not in eq)} (equilibria "
                        "need all of eq_q, eq_u, eq_force)")
    K = eq["eq_q"].shape[0] if eq["eq_q"].ndim == 2 else -1
    for key, width in (("eq_q", n), ("eq_u", m), ("eq_force", n)):
        a = eq[key]
        if a.shape != (K, width):
            raise UserError(f"dataset file {name}: '{key}' must have shape (K, {width}) with K as "
                            f"in 'eq_q', got {a.shape}")
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)) or (
                not np.all(np.isfinite(a))):
            raise UserError(f"dataset file {name}: '{key}' must hold finite numbers")
    return {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in eq.items()}


def make_pairs(
    data: Dataset,
    traj_ids,
    *,
    state: str = "velocity",
    samples: int | None = None,
    seed: int = 0,
    accel: str = "recorded",
) -> PairData:
    """Consecutive-sample pairs (x_k, u_k, u_{k+1}, dt_k, x_{k+1}, ẋ_k) of the given trajectories.

    Pairs never straddle two trajectories. ``samples`` keeps that many pairs drawn at random
    without replacement with ``seed`` (the paper trains physics models on e.g. 8000 randomly
    chosen samples); None keeps all. ``accel``: the q̈ in ẋ_k, "recorded" or "differences".
    """
    x = data.state(state)
    xdot = data.state_derivative(state, accel)
    idx = []
    for tid in np.asarray(traj_ids).tolist():
        rows = data.indices(int(tid))
        if rows.size < 2:
            continue
        idx.append(rows[:-1])
    if not idx:
        raise UserError(f"dataset file {data.path}: the chosen trajectories hold no sample pairs")
    i0 = np.concatenate(idx)
    if samples is not None:
        if samples < 1:
            raise UserError(f"--samples must be >= 1, got {samples}")
        if samples < i0.size:
            rng = np.random.default_rng(seed)
            i0 = np.sort(rng.choice(i0, size=samples, replace=False))
    i1 = i0 + 1
    return PairData(
        x0=x[i0],
        u0=data.u[i0],
        u1=data.u[i1],
        dt=data.t[i1] - data.t[i0],
        x1=x[i1],
        xdot0=None if xdot is None else xdot[i0],
    )


class WindowData(NamedTuple):
    """Windows of h + 1 consecutive samples of one trajectory (multi-step rollout loss); fields
    match ``learn._losses.Windows``: x (B, h + 1, 2n), u (B, h + 1, m), t (B, h + 1)."""

    x: np.ndarray
    u: np.ndarray
    t: np.ndarray

    @property
    def count(self) -> int:
        return int(self.x.shape[0])


def make_windows(
    data: Dataset,
    traj_ids,
    *,
    horizon: int,
    state: str = "velocity",
    samples: int | None = None,
    seed: int = 0,
) -> WindowData:
    """Every window of ``horizon + 1`` consecutive samples inside one trajectory (a window
    starts at each sample that has ``horizon`` successors in its trajectory); ``samples`` keeps
    that many windows drawn at random with ``seed``."""
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
        raise UserError(f"--rollout-steps must be an integer >= 1, got {horizon!r}")
    x = data.state(state)
    starts = []
    for tid in np.asarray(traj_ids).tolist():
        rows = data.indices(int(tid))
        if rows.size > horizon:
            starts.append(rows[: rows.size - horizon])
    if not starts:
        raise UserError(
            f"dataset file {data.path}: no trajectory of the chosen ones has {horizon + 1} "
            "samples for a rollout window"
        )
    s0 = np.concatenate(starts)
    if samples is not None and samples < s0.size:
        s0 = np.sort(np.random.default_rng(seed).choice(s0, size=samples, replace=False))
    idx = s0[:, None] + np.arange(horizon + 1)[None, :]
    return WindowData(x=x[idx], u=data.u[idx], t=data.t[idx])


def trajectories(data: Dataset, traj_ids, *, state: str = "velocity") -> list[dict]:
    """Whole trajectories as dicts of arrays ``t``, ``x`` (T, 2n), ``q``, ``u``, with ``id``."""
    x = data.state(state)
    out = []
    for tid in np.asarray(traj_ids).tolist():
        rows = data.indices(int(tid))
        out.append(
            {"id": int(tid), "t": data.t[rows], "x": x[rows], "q": data.q[rows], "u": data.u[rows]}
        )
    return out
