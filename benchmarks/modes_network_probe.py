"""Does a Lagrangian network on hidden modal coordinates beat the lagged ARX? A probe on a
``softpinn reproduce cosserat`` study for issue 43's next step, not a model of the tool. Prints
JSON.

From a fit of ``benchmarks/modes_probe.py --save FIT`` (N modes, q = C η + q₀, the actuator's
dead time and lag): softpinn's Lagrangian network (eq. 6, ``learn.make_model``) on the N modal
coordinates η, with the modal fit as its linear prior (K = diag ω², D = diag 2ζω, B, c: the
network starts as that linear model, :mod:`learn._prior`), driven by the lag's states y,
stepped by RK4 (``--substeps``, inputs linear between samples), observed through the fit's
C and q₀. Each window starts from the modal fit's moving-horizon estimate of (η, η̇) from the
past samples (fixed). Trained with Adam on the rollout error of ``--window``-sample windows of
the training trajectories (batches of 32), the best validation 5 s rollout error kept (every
100 steps), scored on the test trajectories from their starts with ``softpinn predict``'s
metric beside the linear modal model and the lagged ARX.

    python benchmarks/modes_network_probe.py STUDY FIT --variant clean [--seed 0]

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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path, help="the OUT folder of softpinn reproduce cosserat")
    ap.add_argument("fit", type=Path, help="modes_probe.py --save's file")
    ap.add_argument("--variant", default="clean")
    ap.add_argument("--steps", type=int, default=1500, help="Adam steps")
    ap.add_argument("--window", type=int, default=50, help="training windows [samples]")
    ap.add_argument("--substeps", type=int, default=4)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--observe", choices=("linear", "mlp"), default="linear",
                    help="q = C η + q₀, or plus an MLP of η (last layer starting at zero)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import optax
    from modes_probe import TRUE_ACTUATOR, Modes, _load

    from softpinn.learn import ModelConfig, make_model
    from softpinn.learn._baseline_errors import rollout_errors
    from softpinn.learn._integrate import step
    from softpinn.learn._lagged_arx import fit_lagged_arx
    from softpinn.learn._prior import prior_text

    saved = json.loads(args.fit.read_text())
    s = saved["settings"]
    act = {"study": "study", "true": TRUE_ACTUATOR, "learn": "none"}[s["actuator"]]
    if s["actuator"] != "learn":
        raise SystemExit("modes_network_probe: needs a fit with --actuator learn")
    train, val, test = _load(args.study, args.variant, act)
    lin = Modes(train, modes=s["modes"], past=s["past"], learn=s["actuator"] == "learn",
                ridge=s.get("ridge", 1e-8), kalman=tuple(s["kalman"]) if s.get("kalman") else None)
    th, delay = jnp.asarray(saved["theta"]), saved["delay"]
    N, m, dt = lin.N, lin.m, lin.dt
    p = lin.unpack(th)
    w, z = np.exp(np.asarray(p["lw"])), np.exp(np.asarray(p["lz"]))
    prior = prior_text({"K": np.diag(w * w), "D": np.diag(2 * z * w),
                        "B": np.asarray(p["B"]), "c": np.asarray(p["f"])})
    lay = (args.width, 2)
    net = make_model(ModelConfig("lagrangian", N, m, mass=lay, potential=lay, damping=(16, 2),
                                 input=(16, 2), prior=prior), key=jax.random.PRNGKey(args.seed))
    Ad, Bd, Cf, off = lin.discrete(th)
    C = jnp.asarray(p["C"])
    obs = None
    if args.observe == "mlp":  # a correction to the linear observation, zero at the start
        obs = eqx.nn.MLP(N, lin.n, args.width, 2, activation=jnp.tanh,
                         key=jax.random.PRNGKey(args.seed + 1), dtype=jnp.float64)
        obs = eqx.tree_at(lambda f: (f.layers[-1].weight, f.layers[-1].bias), obs,
                          (jnp.zeros_like(obs.layers[-1].weight),
                           jnp.zeros_like(obs.layers[-1].bias)))
    net = (net, obs)

    def prepare(W):
        """(x0 (B, 2N), y (B, H + 1, m)): the windows' estimated starts and lag states"""
        S0 = lin.starts(th, W[0], W[1])
        x0 = jnp.concatenate([S0[:, 0:2 * N:2], S0[:, 1:2 * N:2]], 1)
        lag, lagB = Ad[2 * N:, 2 * N:], Bd[2 * N:]

        def lags(y0, uh, fu):  # y at the window's start and after each of its H inputs
            u = lin._ua(jnp.concatenate([uh[-1:], fu[:-1]]))
            ys = jax.lax.scan(lambda y, v: (lag @ y + lagB @ v,) * 2, y0, u)[1]
            return jnp.concatenate([y0[None], ys])

        return x0, jax.vmap(lags)(S0[:, 2 * N:], W[0], W[2])

    def roll(pair, x0, y):
        model, g = pair

        def body(x, yy):
            x1 = step(model, x, yy[0], yy[1], dt, substeps=args.substeps, input_hold="linear")
            q = C @ x1[:N] + off
            return x1, q if g is None else q + g(x1[:N])
        return jax.lax.scan(body, x0, (y[:-1], y[1:]))[1]

    def loss(model, x0, y, q):
        pred = jax.vmap(lambda a, b: roll(model, a, b))(x0, y)
        return jnp.mean(jnp.sum((pred - q) ** 2, -1))

    Wt = lin.windows(train, delay, 5, horizon=args.window)
    X0, Y = prepare(Wt)
    Q = Wt[3]
    Wv = lin.windows(val, delay, lin.H // 10)
    X0v, Yv = prepare(Wv)
    validate = eqx.filter_jit(loss)
    start = float(validate(net, X0v, Yv, Wv[3]))
    linear_v = float(jnp.mean(jnp.sum((lin.batch(th, *Wv[:3]) - Wv[3]) ** 2, -1)))
    opt = optax.adam(args.lr)
    state = opt.init(eqx.filter(net, eqx.is_array))

    @eqx.filter_jit
    def train_step(model, state, x0, y, q):
        value, grad = eqx.filter_value_and_grad(loss)(model, x0, y, q)
        updates, state = opt.update(grad, state, model)
        return eqx.apply_updates(model, updates), state, value

    rng = np.random.default_rng(args.seed)
    best = (start, net, 0)
    t0 = time.process_time()
    for it in range(1, args.steps + 1):
        idx = rng.choice(X0.shape[0], min(32, X0.shape[0]), replace=False)
        net, state, _ = train_step(net, state, X0[idx], Y[idx], Q[idx])
        if it % 100 == 0:
            v = float(validate(net, X0v, Yv, Wv[3]))
            print(f"step {it}: validation {v:.4g} (start {start:.4g})", file=sys.stderr,
                  flush=True)
            if v < best[0]:
                best = (v, net, it)
    train_s = time.process_time() - t0
    net = best[1]

    def score(segs, h):
        k = int(round(h / dt))
        W = lin.windows(segs, delay, None, only_start=True)
        x0, y = prepare(W)
        pred = np.asarray(jax.vmap(lambda a, b: roll(net, a, b))(x0, y))[:, :k]
        pred = pred * lin.sq + lin.mq
        return float(np.mean([np.mean(np.sum((pp - sg["q"][1:k + 1]) ** 2, -1))
                              for pp, sg in zip(pred, segs, strict=True)]))

    out = {"settings": vars(args) | {"study": str(args.study), "fit": str(args.fit)},
           "fit": s, "train_cpu_s": train_s, "train_windows": int(X0.shape[0]),
           "validation_5s_normalised": {"linear_modes": linear_v, "network_start": start,
                                        "network_best": best[0], "best_step": best[2]},
           "test": {}}
    for h in (1.0, 5.0):
        out["test"][f"{h:g}s"] = {"network": score(test, h),
                                  "linear_modes": lin.score(th, delay, test, h)}
    if act != "study":
        train, val, test = _load(args.study, args.variant, "study")
    arx = fit_lagged_arx(train + val)
    for h in (1.0, 5.0):
        out["test"][f"{h:g}s"]["lagged_arx"] = rollout_errors(arx, test, h).rollout_error_mean
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
