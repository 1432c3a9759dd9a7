"""Small analytic datasets for the learning tests, written in exactly the dataset file format.

Independent of ``symbolic`` (numpy only): the two-mass spring-damper of eq. 25 (m = 1.0, 1.8;
k = 2.1, 4.6; b = 0.3), optionally forced on the second mass, and a damped, forced pendulum in
(q, p) for the Hamiltonian tests. Integrated with classical RK4 at a step 20x finer than the
output rate, inputs evaluated as continuous sinusoids.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

MSD = {"m": (1.0, 1.8), "k": (2.1, 4.6), "b": 0.3}
#: the same chain as a softpinn spec, with a force on the second mass: runs trained on
#: :func:`make_dataset`'s "msd" data are models of it (the control and export tests)
MSD_SPEC = """
name = "test-msd"
kind = "mass-spring-damper"
masses = [1.0, 1.8]
springs = [2.1, 4.6]
dampers = [0.3, 0.0]
actuation = [[0.0], [1.0]]
"""
#: the same chain with a force on each mass (fully actuated: every output target reachable)
MSD_SPEC_FULL = MSD_SPEC.replace("test-msd", "msd-full").replace("[[0.0], [1.0]]",
                                                                 '"generalized"')


def msd_matrices(*, forced: bool = True):
    """M, K, B, A of eq. 25 (A = [0, 1]^T when forced: a force on the second mass)."""
    m1, m2 = MSD["m"]
    k1, k2 = MSD["k"]
    b = MSD["b"]
    M = np.diag([m1, m2])
    K = np.array([[k1, -k1], [-k1, k1 + k2]])
    B = np.array([[b, -b], [-b, b]])
    A = np.array([[0.0], [1.0]]) if forced else np.zeros((2, 0))
    return M, K, B, A


def _msd_accel(q, qd, u, forced=True):
    M, K, B, A = msd_matrices(forced=forced)
    return np.linalg.solve(M, A @ u - K @ q - B @ qd)


def _pendulum_accel(q, qd, u, forced=True):
    # m = l = 1, g = 9.81, viscous damping 0.2, torque input: q'' = -g sin q - 0.2 q' + u
    return -9.81 * np.sin(q) - 0.2 * qd + (u if forced else 0.0)


SYSTEMS = {
    "msd": {"n": 2, "accel": _msd_accel, "mass": lambda q: msd_matrices()[0]},
    "pendulum": {"n": 1, "accel": _pendulum_accel, "mass": lambda q: np.eye(1)},
}


def simulate(
    system: str = "msd",
    *,
    trajectories: int = 4,
    duration: float = 4.0,
    rate: float = 20.0,
    seed: int = 0,
    forced: bool = True,
    substeps: int = 20,
) -> dict[str, np.ndarray]:
    """Simulate ``trajectories`` runs from random initial states with random sinusoidal inputs.

    Returns the flat arrays of the dataset format (without ``meta``).
    """
    sysd = SYSTEMS[system]
    n = sysd["n"]
    m = 1 if forced else 0
    accel = sysd["accel"]
    rng = np.random.default_rng(seed)
    steps = int(round(duration * rate))
    h = 1.0 / rate / substeps
    out = {k: [] for k in ("t", "q", "qd", "qdd", "p", "u", "traj")}
    for j in range(trajectories):
        q = rng.uniform(-1.0, 1.0, n)
        qd = rng.uniform(-0.5, 0.5, n)
        amp = rng.uniform(0.2, 1.0, m)
        omega = rng.uniform(0.5, 3.0, m)
        phase = rng.uniform(0, 2 * np.pi, m)

        def uf(t, amp=amp, omega=omega, phase=phase):
            return amp * np.sin(omega * t + phase)

        def f(t, x, uf=uf):
            return np.concatenate([x[n:], accel(x[:n], x[n:], uf(t), forced)])

        x = np.concatenate([q, qd])
        t = 0.0
        for k in range(steps + 1):
            u = uf(t)
            a = accel(x[:n], x[n:], u, forced)
            out["t"].append(t)
            out["q"].append(x[:n].copy())
            out["qd"].append(x[n:].copy())
            out["qdd"].append(a)
            out["p"].append(sysd["mass"](x[:n]) @ x[n:])
            out["u"].append(u)
            out["traj"].append(j)
            if k == steps:
                break
            for s in range(substeps):
                ts = t + s * h
                k1 = f(ts, x)
                k2 = f(ts + h / 2, x + h / 2 * k1)
                k3 = f(ts + h / 2, x + h / 2 * k2)
                k4 = f(ts + h, x + h * k3)
                x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t = (k + 1) / rate
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}
    arrays["traj"] = arrays["traj"].astype(np.int64)
    arrays["u"] = arrays["u"].reshape(len(arrays["t"]), m)
    return arrays


def write(path: str | Path, arrays: dict[str, np.ndarray], meta: dict | None = None) -> Path:
    """Write ``arrays`` (t, q, qd, qdd, p, u, traj) plus ``meta`` as a dataset file."""
    path = Path(path)
    meta = meta if meta is not None else {"spec": {"name": "test", "kind": "test"}}
    np.savez(path, **arrays, meta=np.array(json.dumps(meta)))
    return path


def make_dataset(path: str | Path, system: str = "msd", **kw) -> Path:
    """Simulate ``system`` and write it to ``path`` with a meta block like the real files."""
    arrays = simulate(system, **kw)
    meta = {
        "spec": {"name": f"test-{system}", "kind": system},
        "integrator": "rk4",
        "rate": kw.get("rate", 20.0),
        "signals": "sinusoid",
        "seeds": [kw.get("seed", 0)],
        "noise": 0.0,
        "version": "test",
    }
    return write(path, arrays, meta)


def tiny_model_config(kind: str, n: int = 2, m: int = 1, **kw):
    """Small networks for CI-sized training (imports learn lazily: datagen stays numpy-only)."""
    from softpinn.learn._models import ModelConfig

    sizes = dict(mass=(16, 1), potential=(16, 1), damping=(8, 1), input=(8, 1), hidden=(16, 2))
    sizes.update(kw)
    return ModelConfig(kind=kind, n=n, m=m, **sizes)


def blackbox_train_config(**kw):
    """The one black-box TrainConfig the quick tests share, so its program compiles once."""
    from softpinn.learn._train import TrainConfig

    base = dict(
        model=tiny_model_config("blackbox"),
        epochs=12,
        batch_size=64,
        lr=1e-2,
        test_trajectories=(4,),
        checkpoint_every=1000,
    )
    base.update(kw)
    return TrainConfig(**base)
