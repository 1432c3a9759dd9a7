"""Training speed of learn/_train.py; prints one JSON object.

1. ``step``: samples/s of the jitted AdamW training step (one RK4 step per pair, eq. 8/9) per
   model kind, one whole epoch per jitted call (lax.scan over minibatches) against one jitted
   call per minibatch; compile time of the epoch program.
2. ``ensemble``: K seeds trained as one vmapped stacked model against K runs one after another
   (the same compiled single-member program), seconds per epoch of all K.
3. ``time_to_target``: seconds until the test loss first reaches 1e-4, 1e-5, 1e-6 on the
   mass-spring-damper data (eq. 25), Lagrangian net: AdamW with cosine or constant learning
   rate, batch 32, 128 or the full set, and AdamW followed by an L-BFGS finish; every
   configuration is run twice in the process and the second (compiled) run is timed.

Usage: python benchmarks/bench_train.py [--quick] [--n 3] [--batch 1024] [--width 32]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

from softpinn.learn._ensemble import MemberGroup  # noqa: E402
from softpinn.learn._losses import Pairs, pair_loss  # noqa: E402
from softpinn.learn._models import ModelConfig, make_model  # noqa: E402
from softpinn.learn._programs import PROGRAMS  # noqa: E402
from softpinn.learn._train import TrainConfig, train  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from datagen import make_dataset  # noqa: E402


def _random_pairs(n, m, count, dtype, seed=0):
    rng = np.random.default_rng(seed)
    x0 = rng.normal(size=(count, 2 * n))
    u = rng.normal(size=(count, m))
    x1 = x0 + 0.01 * rng.normal(size=(count, 2 * n))
    a = lambda v: jnp.asarray(v, dtype)
    return Pairs(a(x0), a(u), a(u), a(np.full(count, 0.01)), a(x1), None)


def _block(tree):
    jax.block_until_ready(jax.tree.leaves(tree))


def bench_step(kind, n, m, batch, width, depth, steps, dtype, repeats):
    mc = ModelConfig(
        kind=kind,
        n=n,
        m=m,
        mass=(width, depth),
        potential=(width, depth),
        damping=(width, depth),
        input=(width, depth),
        hidden=(width, depth),
        dtype=dtype,
    )
    cfg = TrainConfig(model=mc, epochs=100, batch_size=batch, lr=1e-3)
    pairs = _random_pairs(n, m, batch * steps, jnp.dtype(dtype))
    prog = PROGRAMS.get(cfg, pairs, pairs, batch * steps, batch)
    g = MemberGroup(prog, [0], Path(tempfile.gettempdir()) / "bench.eqx", {})
    active = jnp.ones(1, bool)
    t = time.perf_counter()
    out = prog.epoch_fn(g.params, g.opt_state, g.keys, 0, active)
    _block(out)
    compile_s = time.perf_counter() - t
    # one jitted call per minibatch (no scan), same loss and optimizer
    model = make_model(mc, key=jax.random.PRNGKey(0))
    params, static = eqx.partition(model, eqx.is_array)
    opt = optax.adamw(1e-3)

    @jax.jit
    def one_step(params, state, b):
        loss, grad = jax.value_and_grad(lambda q: pair_loss(eqx.combine(q, static), b))(params)
        upd, state = opt.update(grad, state, params)
        return optax.apply_updates(params, upd), state, loss

    state = opt.init(params)
    batches = [jax.tree.map(lambda a, i=i: a[i * batch : (i + 1) * batch], pairs)
               for i in range(steps)]  # fmt: skip
    _block(one_step(params, state, batches[0]))
    # interleave the two so that load changes on a shared machine hit both alike
    p, s = g.params, g.opt_state
    scan_t, call_t = [], []
    for r in range(repeats):
        t = time.perf_counter()
        p, s, loss = prog.epoch_fn(p, s, g.keys, r + 1, active)
        _block((p, loss))
        scan_t.append(time.perf_counter() - t)
        t = time.perf_counter()
        for b in batches:
            params, state, loss = one_step(params, state, b)
        _block((params, loss))
        call_t.append(time.perf_counter() - t)
    scan_s = float(np.median(scan_t)) / steps
    step_s = float(np.median(call_t)) / steps
    return {
        "kind": kind,
        "compile_epoch_s": round(compile_s, 2),
        "ms_per_step_scan": round(1e3 * scan_s, 3),
        "ms_per_step_per_call": round(1e3 * step_s, 3),
        "samples_per_s_scan": round(batch / scan_s),
        "samples_per_s_per_call": round(batch / step_s),
    }


def bench_ensemble(kind, n, m, batch, width, depth, steps, K, repeats):
    mc = ModelConfig(
        kind=kind, n=n, m=m, mass=(width, depth), potential=(width, depth),
        damping=(width, depth), input=(width, depth), hidden=(width, depth),
    )  # fmt: skip
    cfg = TrainConfig(model=mc, epochs=100, batch_size=batch, lr=1e-3)
    pairs = _random_pairs(n, m, batch * steps, jnp.float64)
    prog = PROGRAMS.get(cfg, pairs, pairs, batch * steps, batch)
    tmp = Path(tempfile.gettempdir()) / "bench.eqx"
    seeds = list(range(K))

    seq_groups = [MemberGroup(prog, [s], tmp, {}) for s in seeds]
    vm_group = MemberGroup(prog, seeds, tmp, {})
    for g in [*seq_groups, vm_group]:  # compile / warm up
        _block(prog.epoch_fn(g.params, g.opt_state, g.keys, 0, jnp.ones(g.K, bool)))
    seq_t, vm_t = [], []
    for r in range(repeats):  # interleaved
        for groups, times in ((seq_groups, seq_t), ([vm_group], vm_t)):
            t = time.perf_counter()
            for g in groups:
                out = prog.epoch_fn(g.params, g.opt_state, g.keys, r + 1, jnp.ones(g.K, bool))
                _block(out)
            times.append(time.perf_counter() - t)
    seq, vm = float(np.median(seq_t)), float(np.median(vm_t))
    return {
        "kind": kind,
        "seeds": K,
        "sequential_s_per_epoch": round(seq, 4),
        "vmap_s_per_epoch": round(vm, 4),
        "vmap_speedup": round(seq / vm, 2),
    }


def bench_time_to_target(quick):
    """Seconds (compiled, second run) until the test loss first reaches a target, for the
    AdamW schedule, batch size and L-BFGS-finish options, Lagrangian net on eq. 25 data."""
    tmp = Path(tempfile.mkdtemp())
    data = make_dataset(tmp / "msd.npz", trajectories=8, duration=5.0)
    mc = ModelConfig(kind="lagrangian", n=2, m=1, mass=(16, 1), potential=(16, 1),
                     damping=(8, 1), input=(8, 1))  # fmt: skip
    E = 100 if quick else 300
    base = dict(model=mc, test_trajectories=(6, 7))
    runs = {
        "adamw_b32_cosine": TrainConfig(epochs=E, batch_size=32, lr=1e-2, **base),
        "adamw_b32_constant": TrainConfig(
            epochs=E, batch_size=32, lr=1e-2, schedule="constant", warmup=0.0, **base
        ),
        "adamw_b128_cosine": TrainConfig(epochs=E, batch_size=128, lr=2e-2, **base),
        "adamw_full_batch_cosine": TrainConfig(epochs=E, batch_size=10**6, lr=3e-2, **base),
        "adamw_b32_cosine_then_lbfgs": TrainConfig(
            epochs=E // 3, batch_size=32, lr=1e-2, lbfgs_steps=100, **base
        ),
    }
    results, hist = {}, {}
    for name, cfg in runs.items():
        for _ in range(2):  # the second run uses the compiled programs
            t = time.perf_counter()
            res = train(data, cfg, tmp / name, force=True)
            wall = time.perf_counter() - t
        hist[name] = res.members[0].history
        results[name] = {
            "wall_s": round(wall, 2),
            "best_test_loss": res.metrics["best_test_loss"]["mean"],
            "train_pairs": res.metrics["train_pairs"],
        }
    out = {}
    for target in (1e-4, 1e-5, 1e-6):
        row = {}
        for name, h in hist.items():
            t0 = h[0]["seconds"]
            hit = next((r for r in h if r["test_loss"] <= target), None)
            row[name] = (
                None
                if hit is None
                else {
                    "seconds": round(hit["seconds"] - t0, 3),
                    "epoch": hit["epoch"],
                    "phase": hit["phase"],
                }
            )
        out[f"target_{target:g}"] = row
    return {"runs": results, **out}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--depth", type=int, default=2)
    ap.add_argument(
        "--kinds",
        nargs="+",
        default=["blackbox", "lagrangian", "hamiltonian", "lagrangian-hessian"],
    )
    ap.add_argument("--skip", nargs="*", default=[], choices=["step", "ensemble", "target"])
    args = ap.parse_args()
    steps = 4 if args.quick else 8
    repeats = 3 if args.quick else 5
    out = {
        "benchmark": "bench_train",
        "backend": jax.default_backend(),
        "device": str(jax.devices()[0]),
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "jax": jax.__version__,
        "settings": {"n": args.n, "m": args.m, "batch": args.batch, "width": args.width,
                     "depth": args.depth, "steps_per_epoch": steps, "repeats": repeats},
    }  # fmt: skip
    if "step" not in args.skip:
        out["step_float64"] = [
            bench_step(k, args.n, args.m, args.batch, args.width, args.depth, steps, "float64",
                       repeats)
            for k in args.kinds
        ]  # fmt: skip
        out["step_float32"] = [
            bench_step(k, args.n, args.m, args.batch, args.width, args.depth, steps, "float32",
                       repeats)
            for k in args.kinds[:2]
        ]  # fmt: skip
    if "ensemble" not in args.skip:
        out["ensemble"] = [
            bench_ensemble(k, args.n, args.m, args.batch // 4, args.width, args.depth, steps, 4,
                           repeats)
            for k in ("blackbox", "lagrangian")
        ]  # fmt: skip
    if "target" not in args.skip:
        out["time_to_target"] = bench_time_to_target(args.quick)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
