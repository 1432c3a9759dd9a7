"""Benchmark the learned dynamics models: training throughput, compile time, rollout time.

For each model kind (structured Lagrangian, Hessian Lagrangian, Hamiltonian, black box), size
n and dtype: one jitted training step (pair loss of eq. 8/9 with one RK4 step per pair, its
gradient and an optax AdamW update) on a batch of 1024 random pairs, with the default network
sizes of ``ModelConfig`` (M, V: 64 x 3; D, A: 16 x 2; black box 128 x 3) and m = n inputs.
Reports samples per second (median and best of timed steps; the kinds of one (n, dtype) are
timed round-robin so that background load hits them alike), the process CPU time of a step,
the XLA compile time of the step, and the time of a 5,000-step rollout of one trajectory
(one jitted ``lax.scan``; its compile time separately).

Prints one JSON object on stdout (per-row progress on stderr). Ratios (structured vs Hessian
vs black box) are computed within the run. ``--quick``: n = 6, float32, fewer repetitions.

    python benchmarks/bench_learn.py --quick
    python benchmarks/bench_learn.py --n 2 3 6 12 --dtypes float64 float32
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import optax  # noqa: E402

from softpinn.learn.integrate import rollout  # noqa: E402
from softpinn.learn.losses import Pairs, pair_loss  # noqa: E402
from softpinn.learn.models import ModelConfig, make_model  # noqa: E402

KINDS = ("lagrangian", "lagrangian-hessian", "hamiltonian", "blackbox")


def _block(tree):
    jax.tree_util.tree_map(lambda a: a.block_until_ready() if isinstance(a, jax.Array) else a, tree)
    return tree


def _pairs(key, n, m, batch, dtype):
    ks = jax.random.split(key, 4)
    dt = jnp.full((batch,), 0.01, dtype)
    return Pairs(
        x0=jax.random.normal(ks[0], (batch, 2 * n), dtype),
        u0=jax.random.normal(ks[1], (batch, m), dtype),
        u1=jax.random.normal(ks[2], (batch, m), dtype),
        dt=dt,
        x1=jax.random.normal(ks[3], (batch, 2 * n), dtype),
    )


def build_train(kind, n, dtype, *, batch, seed=0):
    """A compiled training step for one model kind; returns (call, state, compile seconds)."""
    cfg = ModelConfig(kind=kind, n=n, m=n, dtype=dtype)
    key_model, key_data = jax.random.split(jax.random.PRNGKey(seed))
    model = make_model(cfg, key=key_model)
    opt = optax.adamw(1e-3)
    opt_state = opt.init(eqx.filter(model, eqx.is_array))

    @eqx.filter_jit
    def train_step(model, opt_state, pairs):
        loss, grads = eqx.filter_value_and_grad(pair_loss)(model, pairs)
        updates, opt_state = opt.update(grads, opt_state, eqx.filter(model, eqx.is_array))
        return eqx.apply_updates(model, updates), opt_state, loss

    pairs = _pairs(key_data, n, n, batch, jnp.dtype(dtype))
    t0 = time.perf_counter()
    compiled = train_step.lower(model, opt_state, pairs).compile()
    compile_s = time.perf_counter() - t0
    state = {"model": model, "opt_state": opt_state, "loss": None}

    def call():
        state["model"], state["opt_state"], state["loss"] = _block(
            compiled(state["model"], state["opt_state"], pairs)
        )

    call()  # warm-up
    return call, state, compile_s


def bench_train_group(kinds, n, dtype, *, batch, reps):
    """Compile every kind's step, then time them round-robin so that load noise is shared."""
    built = {k: build_train(k, n, dtype, batch=batch) for k in kinds}
    wall = {k: [] for k in kinds}
    cpu = {k: [] for k in kinds}
    for _ in range(reps):
        for k in kinds:
            t0, c0 = time.perf_counter(), time.process_time()
            built[k][0]()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    out = {}
    for k in kinds:
        step_s = statistics.median(wall[k])
        out[k] = {
            "step_ms": 1e3 * step_s,
            "step_ms_min": 1e3 * min(wall[k]),
            "step_cpu_ms_min": 1e3 * min(cpu[k]),
            "samples_per_s": batch / step_s,
            "samples_per_s_best": batch / min(wall[k]),
            "compile_s": built[k][2],
            "finite": bool(jnp.isfinite(built[k][1]["loss"])),
        }
    return out


def bench_rollout(kind, n, dtype, *, steps, seed=0):
    cfg = ModelConfig(kind=kind, n=n, m=n, dtype=dtype)
    model = make_model(cfg, key=jax.random.PRNGKey(seed))
    dt = jnp.dtype(dtype)
    t = jnp.arange(steps, dtype=dt) * 0.01
    u = 0.1 * jnp.sin(t)[:, None] * jnp.ones((1, n), dt)
    x0 = 0.1 * jnp.ones(2 * n, dt)
    fn = eqx.filter_jit(lambda model, x0, u, t: rollout(model, x0, u, t))
    t0 = time.perf_counter()
    _block(fn(model, x0, u, t))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    xs = _block(fn(model, x0, u, t))
    run = time.perf_counter() - t0
    return {
        "rollout_s": run,
        "rollout_compile_s": max(first - run, 0.0),
        "rollout_finite": bool(jnp.all(jnp.isfinite(xs))),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="n = 6, float32, few repetitions")
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--n", nargs="+", type=int, default=[2, 3, 6, 12])
    ap.add_argument("--dtypes", nargs="+", default=["float64", "float32"])
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--rollout-steps", type=int, default=5000)
    ap.add_argument("--no-rollout", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.n, args.dtypes, args.reps = [6], ["float32"], 5

    results = []
    for dtype in args.dtypes:
        for n in args.n:
            group = bench_train_group(args.kinds, n, dtype, batch=args.batch, reps=args.reps)
            for kind in args.kinds:
                row = {"kind": kind, "n": n, "dtype": dtype, "batch": args.batch, **group[kind]}
                if not args.no_rollout:
                    row.update(bench_rollout(kind, n, dtype, steps=args.rollout_steps))
                results.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)

    ratios = []
    for dtype in args.dtypes:
        for n in args.n:
            by = {r["kind"]: r for r in results if r["n"] == n and r["dtype"] == dtype}
            if "lagrangian" not in by:
                continue
            entry = {"n": n, "dtype": dtype}
            for key in ("step_ms", "step_ms_min"):
                s = by["lagrangian"][key]
                if "lagrangian-hessian" in by:
                    entry[f"hessian_over_structured_{key}"] = by["lagrangian-hessian"][key] / s
                if "blackbox" in by:
                    entry[f"structured_over_blackbox_{key}"] = s / by["blackbox"][key]
                if "hamiltonian" in by:
                    entry[f"hamiltonian_over_structured_{key}"] = by["hamiltonian"][key] / s
            ratios.append(entry)

    print(
        json.dumps(
            {
                "benchmark": "learn",
                "jax": jax.__version__,
                "equinox": eqx.__version__,
                "backend": jax.default_backend(),
                "device": str(jax.devices()[0]),
                "cpu_count": os.cpu_count(),
                "machine": platform.machine(),
                "settings": {
                    "batch": args.batch,
                    "reps": args.reps,
                    "rollout_steps": None if args.no_rollout else args.rollout_steps,
                    "nets": "M, V 64x3; D, A 16x2; black box 128x3; softplus; m = n",
                    "loss": "pair loss eq. 8/9, one RK4 step, AdamW",
                },
                "results": results,
                "ratios": ratios,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
