"""How far is a linear model in hidden modal coordinates from the lagged ARX? A probe on a
``softpinn reproduce cosserat`` study's recordings for issue 43's next step (a physics network
with hidden coordinates), not a model of the tool. Prints JSON.

The model: N mass-spring-damper modes driven by the inputs, observed through a linear map,

    η̈_j + 2 ζ_j ω_j η̇_j + ω_j² η_j = b_jᵀ y + f_j,    q = C η + q₀,

(M = I, K, D diagonal: a linear Lagrangian system in modal coordinates, what a Lagrangian
network on N coordinates with a linear prior would start as), discretised exactly (zero-order
hold). ``--actuator study`` drives it with the study's identified actuator output (y), ``true``
with the simulator's (``0.2:0.15``, for reference only), ``learn`` with the commands delayed by
a dead time from a grid and passed through a first-order lag whose time constant is one more
parameter of the fit (its states propagated from the input history). The modal state at a
window's start is estimated by least squares from the window's past ``--past`` samples of q
(a moving-horizon estimate with the model itself; at a trajectory's start from the past
extrapolated along q̇0, inputs held, as the lagged ARX starts; ``--kalman`` estimates it by a
Kalman filter over those samples instead). Fitted by Levenberg-Marquardt on
the rollout error of 5 s windows of the training trajectories (JAX's forward-mode Jacobian),
from ``--restarts`` starts with paired frequencies (a rod bends in two planes); the best on the
training windows scored on the test trajectories from their starts, with ``softpinn predict``'s
metric, beside the lagged ARX of the same training and validation trajectories.

    python benchmarks/modes_probe.py STUDY --variant clean --modes 6 --actuator learn

Used in RESULTS.md ("Hidden modes", 28 Nov 2026).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
TRUE_ACTUATOR = "0.2:0.15"  # symbolic/standin/_cosserat.py's defaults


def _load(root: Path, variant: str, actuator: str):
    """(train, validation, test) segments under ``actuator`` ("study": the identified one)."""
    from memory_probe import _study

    return _study(root, variant, None if actuator == "study" else actuator)


class Modes:
    """The modal model on a study's training trajectories: data windows, the exact discrete
    model of a parameter vector, its moving-horizon start and rollouts, its fit (the module's
    doc). Everything in units normalised by the training trajectories' mean and std."""

    HIST = 100  # input samples behind the past window that settle the lag's states

    def __init__(self, train, *, modes: int, past: int, learn: bool, ridge: float = 1e-8,
                 kalman: tuple[float, float] | None = None):
        import jax
        import jax.numpy as jnp

        jax.config.update("jax_enable_x64", True)
        self.jax, self.jnp = jax, jnp
        self.N, self.P, self.learn, self.ridge, self.kalman = modes, past, learn, ridge, kalman
        self.dt = float(np.median(np.diff(train[0]["t"])))
        self.n, self.m = train[0]["q"].shape[1], train[0]["u"].shape[1]
        qs = np.concatenate([s["q"] for s in train])
        us = np.concatenate([s["u"] for s in train])
        self.mq, self.sq = qs.mean(0), qs.std(0)
        self.mu, self.su = us.mean(0), us.std(0) + 1e-12
        self.S = 2 * modes + self.m  # modes, then the lag's states (used with learn)
        self.H = int(round(5.0 / self.dt))
        self.sizes = {"lw": modes, "lz": modes, "B": modes * self.m, "C": self.n * modes,
                      "off": self.n, "f": modes, "ltau": 1}
        self.batch = jax.jit(jax.vmap(self.one, in_axes=(None, 0, 0, 0)))
        self.starts = jax.jit(jax.vmap(self.start, in_axes=(None, 0, 0)))

    def windows(self, segs, delay, stride, *, horizon=None, only_start=False):
        """per window: input history (HIST + P, m) oldest first, past q (P, n), future inputs
        (H, m), future q (H, n), normalised"""
        from softpinn.actuator import delayed

        H, P, dt = horizon or self.H, self.P, self.dt
        cols = ([], [], [], [])
        for s in segs:
            q = (s["q"] - self.mq) / self.sq
            u = s["u"]
            if self.learn:
                u = np.stack([delayed(s["t"], c, delay) for c in u.T], 1)
            u = (u - self.mu) / self.su
            if not only_start:
                for k in range(P - 1, len(q) - H - 1, stride):
                    cols[0].append(u[np.clip(np.arange(k - P - self.HIST + 1, k + 1), 0, None)])
                    cols[1].append(q[k - P + 1:k + 1])
                    cols[2].append(u[k + 1:k + H + 1])
                    cols[3].append(q[k + 1:k + H + 1])
            cols[0].append(np.repeat(u[:1], self.HIST + P, 0))
            cols[1].append(q[0] - dt * s["qd"][0] / self.sq * np.arange(P)[::-1, None])
            cols[2].append(u[1:H + 1])
            cols[3].append(q[1:H + 1])
        return [self.jnp.asarray(np.array(c)) for c in cols]

    def unpack(self, th):
        out, i = {}, 0
        for k, size in self.sizes.items():
            out[k] = th[i:i + size]
            i += size
        out["B"], out["C"] = out["B"].reshape(self.N, self.m), out["C"].reshape(self.n, self.N)
        return out

    def initial(self, rng):
        N, m, n = self.N, self.m, self.n
        freq = np.repeat(np.geomspace(3.0, 80.0, (N + 1) // 2), 2)[:N]
        return np.concatenate([np.log(freq * np.exp(0.2 * rng.standard_normal(N))),
                               np.log(np.full(N, 0.5)), 0.3 * rng.standard_normal(N * m),
                               0.3 * rng.standard_normal(n * N), np.zeros(n), np.zeros(N),
                               [np.log(0.2)]])

    def continuous(self, th):
        """(A, Bc): the state's rate A s + Bc [u, 1]"""
        jnp, N, m, S = self.jnp, self.N, self.m, self.S
        p = self.unpack(th)
        w, z = jnp.exp(p["lw"]), jnp.exp(p["lz"])
        i = jnp.arange(N)
        A = jnp.zeros((S, S)).at[2 * i, 2 * i + 1].set(1.0)
        A = A.at[2 * i + 1, 2 * i].set(-w * w).at[2 * i + 1, 2 * i + 1].set(-2 * z * w)
        Bc = jnp.zeros((S, m + 1)).at[2 * i + 1, m].set(p["f"])
        if self.learn:  # modes driven by the lag's states, the lag by the (delayed) command
            A = A.at[2 * i[:, None] + 1, 2 * N + jnp.arange(m)[None]].set(p["B"])
            rate = jnp.exp(-p["ltau"][0])
            A = A.at[2 * N + jnp.arange(m), 2 * N + jnp.arange(m)].set(-rate)
            Bc = Bc.at[2 * N + jnp.arange(m), jnp.arange(m)].set(rate)
        else:
            Bc = Bc.at[2 * i + 1, :m].set(p["B"])
        return A, Bc

    def discrete(self, th):
        jnp, S, m = self.jnp, self.S, self.m
        A, Bc = self.continuous(th)
        big = jnp.zeros((S + m + 1, S + m + 1)).at[:S, :S].set(A).at[:S, S:].set(Bc)
        E = self.jax.scipy.linalg.expm(big * self.dt)
        i = jnp.arange(self.N)
        Cf = jnp.zeros((self.n, S)).at[:, 2 * i].set(self.unpack(th)["C"])
        return E[:S, :S], E[:S, S:], Cf, self.unpack(th)["off"]

    def _ua(self, u):
        return self.jnp.concatenate([u, self.jnp.ones(u.shape[:-1] + (1,))], -1)

    def start(self, th, uh, pq):
        """the state at a window's last past sample: lag states from the input history,
        modal states by least squares on the past q"""
        jax, jnp, N, m, S = self.jax, self.jnp, self.N, self.m, self.S
        Ad, Bd, Cf, off = self.discrete(th)
        w0 = jnp.zeros(m)
        if self.learn:
            lag, lagB = Ad[2 * N:, 2 * N:], Bd[2 * N:]
            w0 = jax.lax.scan(lambda w, u: (lag @ w + lagB @ u, None), uh[0],
                              self._ua(uh[:self.HIST]))[0]

        if self.kalman is not None:
            return self._filtered(Ad, Bd, Cf, off, w0, uh, pq)

        def body(carry, u):
            Phi, f = carry
            return (Ad @ Phi, Ad @ f + Bd @ u), (Phi, f)

        first = (jnp.eye(S)[:, :2 * N], jnp.zeros(S).at[2 * N:].set(w0))
        _, (Phis, fs) = jax.lax.scan(body, first, self._ua(uh[self.HIST:]))
        O = jnp.einsum("ns,psr->pnr", Cf, Phis).reshape(-1, 2 * N)
        y = (pq - off - fs @ Cf.T).reshape(-1)
        G = O.T @ O  # the ridge relative to its mean diagonal: hidden modes the past does
        # not show are pulled to rest
        s0 = jnp.linalg.solve(G + self.ridge * jnp.trace(G) / (2 * N) * jnp.eye(2 * N), O.T @ y)
        return Phis[-1] @ s0 + fs[-1]

    def _filtered(self, Ad, Bd, Cf, off, w0, uh, pq):
        """the state at the last past sample by a Kalman filter over the past samples: modes
        from rest with a wide prior, process noise on the modal rates, measurement noise
        (``kalman`` = (process, measurement) variances, normalised units)"""
        jax, jnp, N, S = self.jax, self.jnp, self.N, self.S
        qv, rv = self.kalman
        P0 = jnp.zeros((S, S)).at[jnp.arange(2 * N), jnp.arange(2 * N)].set(10.0)
        Q = jnp.zeros((S, S)).at[jnp.arange(1, 2 * N, 2), jnp.arange(1, 2 * N, 2)].set(qv)
        R = rv * jnp.eye(self.n)

        def update(s, Pm, y):
            G = Cf @ Pm @ Cf.T + R
            K = jnp.linalg.solve(G, Cf @ Pm).T
            return s + K @ (y - off - Cf @ s), Pm - K @ Cf @ Pm

        def body(carry, inp):
            s, Pm = update(*carry, inp[0])
            return (Ad @ s + Bd @ inp[1], Ad @ Pm @ Ad.T + Q), None

        s0 = jnp.zeros(S).at[2 * N:].set(w0)
        u = self._ua(uh[self.HIST:])
        (s, Pm), _ = jax.lax.scan(body, (s0, P0), (pq[:-1], u[:-1]))
        return update(s, Pm, pq[-1])[0]

    def one(self, th, uh, pq, fu):
        """q̂ (H, n) of one window"""
        Ad, Bd, Cf, off = self.discrete(th)

        def roll(s, u):
            s1 = Ad @ s + Bd @ u
            return s1, Cf @ s1 + off

        u = self._ua(self.jnp.concatenate([uh[-1:], fu[:-1]]))
        return self.jax.lax.scan(roll, self.start(th, uh, pq), u)[1]

    def lm(self, th, W, iterations):
        jax, jnp = self.jax, self.jnp
        res = jax.jit(lambda t: (self.batch(t, *W[:3]) - W[3]).reshape(-1))
        jac = jax.jit(jax.jacfwd(lambda t: (self.batch(t, *W[:3]) - W[3]).reshape(-1)))
        r = res(th)
        e, lam = float(r @ r), 1e-2
        for _ in range(iterations):
            J = jac(th)
            g, Hm = J.T @ r, J.T @ J
            while lam < 1e8:
                th2 = th + jnp.linalg.solve(Hm + lam * jnp.diag(jnp.diag(Hm) + 1e-12), -g)
                r2 = res(th2)
                e2 = float(r2 @ r2)
                if np.isfinite(e2) and e2 < e:
                    th, r, e, lam = th2, r2, e2, lam / 3
                    break
                lam *= 4
            else:
                break
        return th, e / W[3].size

    def score(self, th, delay, segs, h):
        """predict's metric from each trajectory's start, h seconds"""
        k = int(round(h / self.dt))
        W = self.windows(segs, delay, None, only_start=True)
        pred = np.asarray(self.batch(th, *W[:3]))[:, :k] * self.sq + self.mq
        return float(np.mean([np.mean(np.sum((p - s["q"][1:k + 1]) ** 2, -1))
                              for p, s in zip(pred, segs, strict=True)]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path, help="the OUT folder of softpinn reproduce cosserat")
    ap.add_argument("--variant", default="clean")
    ap.add_argument("--modes", type=int, default=6)
    ap.add_argument("--past", type=int, default=25, help="samples of q behind a window's start")
    ap.add_argument("--actuator", choices=("study", "true", "learn"), default="learn")
    ap.add_argument("--delays", default="0.08,0.1,0.12,0.14,0.16,0.18",
                    help="dead times tried with --actuator learn [s]")
    ap.add_argument("--restarts", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ridge", type=float, default=1e-8,
                    help="of the start's least squares, relative to its mean diagonal")
    ap.add_argument("--kalman", type=float, nargs=2, metavar=("PROCESS", "MEASUREMENT"),
                    help="start by a Kalman filter with these variances instead")
    ap.add_argument("--save", type=Path, help="write the fit here (modes_network_probe.py)")
    args = ap.parse_args(argv)

    from softpinn.learn._baseline_errors import rollout_errors
    from softpinn.learn._lagged_arx import fit_lagged_arx

    act = {"study": "study", "true": TRUE_ACTUATOR, "learn": "none"}[args.actuator]
    train, val, test = _load(args.study, args.variant, act)
    model = Modes(train, modes=args.modes, past=args.past, learn=args.actuator == "learn",
                  ridge=args.ridge, kalman=args.kalman)
    rng = np.random.default_rng(args.seed)
    delays = [float(d) for d in args.delays.split(",")] if model.learn else [0.0]
    t0 = time.process_time()
    fits = []
    for d in delays:
        W = model.windows(train, d, model.H // 4)
        for _ in range(args.restarts):
            th, err = model.lm(model.jnp.asarray(model.initial(rng)), W, args.iterations)
            fits.append((err, d, th))
            print(f"delay {d:g}: training windows {err:.4g}", file=sys.stderr, flush=True)
    fit_s = time.process_time() - t0
    err, delay, th = min(fits, key=lambda f: f[0])
    scores = {h: model.score(th, delay, test, h) for h in (1.0, 5.0)}
    if act != "study":  # the lagged ARX as the tool fits it: under the study's actuator
        train, val, test = _load(args.study, args.variant, "study")
    arx = fit_lagged_arx(train + val)
    p = model.unpack(th)
    out = {"study": str(args.study), "settings": vars(args) | {
        "study": str(args.study), "save": str(args.save)}, "fit_cpu_s": fit_s,
        "training_error": err, "test": {},
        "modes": {"omega": np.exp(np.asarray(p["lw"])).round(3).tolist(),
                  "zeta": np.exp(np.asarray(p["lz"])).round(3).tolist()},
        "lagged_arx": arx.describe()}
    if model.learn:
        out["actuator"] = {"time_constant": float(np.exp(p["ltau"][0])), "delay": delay}
    for h in (1.0, 5.0):
        out["test"][f"{h:g}s"] = {"modes": scores[h], "lagged_arx": rollout_errors(
            arx, test, h).rollout_error_mean}
    if args.save:
        args.save.write_text(json.dumps(out | {"theta": np.asarray(th).tolist(),
                                               "delay": delay}))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
