"""Time one training step of each model kind side by side (issue 18's per-step cost).

One jitted training step = the pair loss (eq. 8/9, one RK4 step per pair), its gradient and an
optax AdamW update, on a batch of random pairs, with the default network sizes of
:class:`learn._model_config.ModelConfig` (M, V: 64 x 3; D, A: 16 x 2; black box 128 x 3) and m = n.
The kinds of one (n, dtype) are compiled first, then timed round-robin, so that background load
on a shared machine hits them alike: compare ratios within one call, not times across calls.
Used by ``benchmarks/bench_learn.py`` and by the "fast" study of ``softpinn reproduce
challenges`` (:mod:`bridge.challenges.fast`).
"""

from __future__ import annotations

import statistics
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import optax

from softpinn.learn._losses import Pairs, pair_loss
from softpinn.learn._models import ModelConfig, ensure_dtype, make_model

#: The model kinds, in the order the benchmark reports them.
KINDS = ("lagrangian", "lagrangian-hessian", "hamiltonian", "blackbox")


def block(tree):
    """Wait for every array of ``tree`` (JAX dispatches asynchronously)."""
    jax.tree_util.tree_map(lambda a: a.block_until_ready() if isinstance(a, jax.Array) else a, tree)
    return tree


def random_pairs(key, n, m, batch, dtype) -> Pairs:
    """``batch`` random pairs (standard normal states and inputs, dt = 0.01)."""
    ks = jax.random.split(key, 4)
    return Pairs(
        x0=jax.random.normal(ks[0], (batch, 2 * n), dtype),
        u0=jax.random.normal(ks[1], (batch, m), dtype),
        u1=jax.random.normal(ks[2], (batch, m), dtype),
        dt=jnp.full((batch,), 0.01, dtype),
        x1=jax.random.normal(ks[3], (batch, 2 * n), dtype),
    )


def step_gflop(compiled) -> float | None:
    """The floating-point operations of one compiled step, in 10⁹, as XLA's cost analysis counts
    them (every dot and elementwise operation of the optimised program; None where the backend
    gives no count). The work a step does, whatever the machine: the ratio of two kinds' counts
    is what their times' ratio tends to when both run at the same speed."""
    inner = getattr(compiled, "compiled", compiled)  # equinox wraps jax.stages.Compiled
    try:
        cost = inner.cost_analysis()
    except Exception:  # noqa: BLE001 - some backends have none
        return None
    if isinstance(cost, list):
        cost = cost[0] if cost else {}
    flops = (cost or {}).get("flops")
    return None if flops is None or flops < 0 else float(flops) / 1e9


def build_train(kind, n, dtype, *, batch, seed=0):
    """A compiled training step for one model kind; returns (call, state, compile seconds)."""
    ensure_dtype(dtype)
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

    pairs = random_pairs(key_data, n, n, batch, jnp.dtype(dtype))
    t0 = time.perf_counter()
    compiled = train_step.lower(model, opt_state, pairs).compile()
    compile_s = time.perf_counter() - t0
    state = {"model": model, "opt_state": opt_state, "loss": None, "gflop": step_gflop(compiled)}

    def call():
        state["model"], state["opt_state"], state["loss"] = block(
            compiled(state["model"], state["opt_state"], pairs)
        )

    call()  # warm-up
    return call, state, compile_s


def time_train_steps(kinds, n, dtype, *, batch, reps) -> dict[str, dict]:
    """Compile every kind's step, then time ``reps`` rounds of them round-robin; per kind: the
    median and best wall time of a step (ms), the best process CPU time, samples per second,
    the compile time, the step's floating-point operations (:func:`step_gflop`) and whether the
    last loss was finite."""
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
            "gflop": built[k][1]["gflop"],
            "finite": bool(jnp.isfinite(built[k][1]["loss"])),
        }
    return out
