"""Benchmark the learned dynamics models: training throughput, compile time, rollout time.

For each model kind (structured Lagrangian, Hessian Lagrangian, Hamiltonian, black box), size
n and dtype: one jitted training step (pair loss of eq. 8/9 with one RK4 step per pair, its
gradient and an optax AdamW update) on a batch of 1024 random pairs, with the default network
sizes of ``ModelConfig`` (M, V: 64 x 3; D, A: 16 x 2; black box 128 x 3) and m = n inputs.
Reports samples per second (median and best of timed steps; the kinds of one (n, dtype) are
timed round-robin so that background load hits them alike), the process CPU time of a step,
the XLA compile time of the step, its floating-point operations as XLA counts them (the
ratio of two kinds' counts is their time ratio at equal speed), and the time of a 5,000-step
rollout of one trajectory (one jitted ``lax.scan``; its compile time separately).

Prints one JSON object on stdout (per-row progress on stderr). Ratios (structured vs Hessian
vs black box) are computed within the run. ``--quick``: n = 6, float32, fewer repetitions. The
step timing is :mod:`softpinn.learn._steptime` (shared with ``softpinn reproduce challenges``).

    python benchmarks/bench_learn.py --quick
    python benchmarks/bench_learn.py --n 2 3 6 12 --dtypes float64 float32
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from softpinn.learn._integrate import rollout  # noqa: E402
from softpinn.learn._models import ModelConfig, make_model  # noqa: E402
from softpinn.learn._steptime import (  # noqa: E402
    KINDS,
    block,
    time_train_steps,
)


def bench_rollout(kind, n, dtype, *, steps, seed=0):
    cfg = ModelConfig(kind=kind, n=n, m=n, dtype=dtype)
    model = make_model(cfg, key=jax.random.PRNGKey(seed))
    dt = jnp.dtype(dtype)
    t = jnp.arange(steps, dtype=dt) * 0.01
    u = 0.1 * jnp.sin(t)[:, None] * jnp.ones((1, n), dt)
    x0 = 0.1 * jnp.ones(2 * n, dt)
    fn = eqx.filter_jit(lambda model, x0, u, t: rollout(model, x0, u, t))
    t0 = time.perf_counter()
    block(fn(model, x0, u, t))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    xs = block(fn(model, x0, u, t))
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
            group = time_train_steps(args.kinds, n, dtype, batch=args.batch, reps=args.reps)
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
            base = by["lagrangian"].get("gflop")
            for other, key in (("lagrangian-hessian", "hessian_over_structured_flops"),
                               ("hamiltonian", "hamiltonian_over_structured_flops")):
                if base and by.get(other, {}).get("gflop") is not None:
                    entry[key] = by[other]["gflop"] / base
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
