"""Does a network with memory beat the lagged ARX? A probe on a ``softpinn reproduce cosserat``
study's recordings, not a model of the tool (issue 43's next step). Prints JSON.

The lagged ARX (``learn/_lagged_arx.py``) of the study's training and validation trajectories
(its bending coordinates, under the study's identified actuator), plus an MLP on the same lagged
features (p past samples of q and u, normalised by the training data; 2 hidden layers of 64,
tanh, last layer zero: it starts as the lagged ARX), q_{k+1} = ARX(...) + 0.01 σ_q MLP(...):
a NARX model. Trained with Adam on the rollout error of windows of the training trajectories
from their measured past (batches of 64), the best validation 5 s rollout error kept (every 100
steps), scored with ``softpinn predict``'s metric on the test trajectories (from each one's
start, the past extrapolated along q̇0 and the inputs held, as the lagged ARX is).

    python benchmarks/memory_probe.py STUDY --variant clean [--steps 3000] [--window 50]

Used in RESULTS.md ("The lagged ARX", 28 Nov 2026).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def _study(root: Path, variant: str, actuator_text: str | None = None):
    """(train, validation, test) segments of the bending coordinates, the inputs through the
    study's identified actuator (or ``actuator_text``, ``TAU:DELAY`` or ``none``)."""
    from softpinn.bridge.cosserat.stages import load_dataset, run_actuator, with_actuator

    def sub(d):
        return json.loads(json.dumps(d).replace("$OUT", str(root)))

    imported = sub(json.loads((root / variant / "import" / "done.json").read_text())["result"])
    actuator = json.loads((root / variant / "actuator" / "done.json").read_text())["result"]
    data = load_dataset(imported["path"])
    felt = with_actuator(data, run_actuator(actuator_text or actuator["text"], data.m))

    def segs(ids):
        out = []
        for i in ids:
            r = felt.indices(i)
            out.append({"id": i, "t": felt.t[r], "q": felt.q[r][:, :2], "qd": felt.qd[r][:, :2],
                        "u": felt.u[r]})
        return out

    return segs(imported["train"]), segs(imported["validation"]), segs(imported["test"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path, help="the OUT folder of softpinn reproduce cosserat")
    ap.add_argument("--variant", default="clean")
    ap.add_argument("--steps", type=int, default=3000, help="Adam steps")
    ap.add_argument("--window", type=int, default=50, help="training windows [samples]")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from softpinn.learn._baseline_errors import rollout_errors
    from softpinn.learn._lagged_arx import fit_lagged_arx

    jax.config.update("jax_enable_x64", True)
    train, val, test = _study(args.study, args.variant)
    dt = float(np.median(np.diff(train[0]["t"])))
    t0 = time.process_time()
    arx = fit_lagged_arx(train + val)
    fit_s = time.process_time() - t0
    p, n, m = arx.order, arx.n, arx.m
    A = jnp.asarray(np.concatenate(list(arx.A), 1))
    B = jnp.asarray(np.concatenate(list(arx.B), 1))
    c = jnp.asarray(arx.c)
    q_all = np.concatenate([s["q"] for s in train])
    u_all = np.concatenate([s["u"] for s in train])
    mq, sq = jnp.asarray(q_all.mean(0)), jnp.asarray(q_all.std(0))
    mu, su = jnp.asarray(u_all.mean(0)), jnp.asarray(u_all.std(0) + 1e-9)
    mlp = eqx.nn.MLP(p * (n + m), n, 64, 2, activation=jnp.tanh,
                     key=jax.random.PRNGKey(args.seed), dtype=jnp.float64)
    last = mlp.layers[-1]
    mlp = eqx.tree_at(lambda f: (f.layers[-1].weight, f.layers[-1].bias), mlp,
                      (jnp.zeros_like(last.weight), jnp.zeros_like(last.bias)))

    def roll(net, past, upast, u_next):
        """q̂ after past (p, n) and upast (p, m), newest first, under u_next (H, m)."""
        def body(carry, u):
            past, upast = carry
            feat = jnp.concatenate([((past - mq) / sq).reshape(-1),
                                    ((upast - mu) / su).reshape(-1)])
            nxt = A @ past.reshape(-1) + B @ upast.reshape(-1) + c + 0.01 * sq * net(feat)
            return (jnp.concatenate([nxt[None], past[:-1]]),
                    jnp.concatenate([u[None], upast[:-1]])), nxt
        return jax.lax.scan(body, (past, upast), u_next)[1]

    def windows(segs, H, stride):
        cols = ([], [], [], [])
        for s in segs:
            for a in range(p - 1, len(s["q"]) - H - 1, stride):
                back = a - np.arange(p)
                for col, v in zip(cols, (s["q"][back], s["u"][back], s["u"][a + 1:a + H + 1],
                                         s["q"][a + 1:a + H + 1]), strict=True):
                    col.append(v)
        return [jnp.asarray(np.array(col)) for col in cols]

    def loss(net, P, U, N, Q):
        pred = jax.vmap(lambda a, b, u: roll(net, a, b, u))(P, U, N)
        return jnp.mean(jnp.sum((pred - Q) ** 2, -1))

    horizon = int(round(5.0 / dt))
    W, Wv = windows(train, args.window, 5), windows(val, horizon, horizon // 10)
    opt = optax.adam(args.lr)
    state = opt.init(eqx.filter(mlp, eqx.is_array))

    @eqx.filter_jit
    def step(net, state, P, U, N, Q):
        value, grad = eqx.filter_value_and_grad(loss)(net, P, U, N, Q)
        updates, state = opt.update(grad, state, net)
        return eqx.apply_updates(net, updates), state, value

    validate = eqx.filter_jit(loss)
    best = (float(validate(mlp, *Wv)), mlp, 0)
    start = best[0]
    rng = np.random.default_rng(args.seed)
    t0 = time.process_time()
    for it in range(1, args.steps + 1):
        idx = rng.choice(W[0].shape[0], min(64, W[0].shape[0]), replace=False)
        mlp, state, _ = step(mlp, state, *[w[idx] for w in W])
        if it % 100 == 0 and (v := float(validate(mlp, *Wv))) < best[0]:
            best = (v, mlp, it)
    train_s = time.process_time() - t0
    net = best[1]

    def predict(segs, h):
        errs = []
        for s in segs:
            k = int(round(h / dt)) + 1
            q, qd, u = s["q"][:k], s["qd"][0], s["u"][:k]
            past = jnp.asarray(np.array([q[0] - j * dt * qd for j in range(p)]))
            pred = np.asarray(roll(net, past, jnp.asarray(np.repeat(u[:1], p, 0)),
                                   jnp.asarray(u[1:])))
            errs.append(float(np.mean(np.sum((pred - q[1:]) ** 2, -1))))
        return float(np.mean(errs))

    out = {"study": str(args.study), "variant": args.variant, "settings": vars(args) | {
        "study": str(args.study)}, "lagged_arx": {"order": p, "fit": arx.info["fit"],
                                                  "fit_cpu_s": fit_s},
           "validation_5s": {"lagged_arx": start, "narx": best[0], "best_step": best[2]},
           "train_cpu_s": train_s, "test": {}}
    for h in (1.0, 5.0):
        out["test"][f"{h:g}s"] = {"narx": predict(test, h), "lagged_arx": rollout_errors(
            arx, test, h).rollout_error_mean}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
