"""Benchmark the exact model in JAX (softpinn.bridge.exact) against CasADi; prints JSON.

Parts (each in its own process, so that the XLA thread flags apply before jax is imported):

* ``forward``: forward dynamics per state for task5 (two spatial segments, n = 6) and planar
  PCC arms of 1 and 2 segments, batch 10,000, float64, on ONE core (``sched_setaffinity`` and
  XLA's single-thread flags): CasADi's interpreter (``TrueModel.qdd`` batched), CasADi's
  compiled C with ``map`` (serial), the JAX translation (``jit(vmap)``); translate, trace and
  XLA-compile times; the largest difference JAX - C. ``--segments 4`` adds a 4-segment arm
  (translate + compile time only).
* ``simulate``: 1,000 trajectories of 10 s of task5 with fixed-step RK4 in JAX on two cores
  (two halves run concurrently), and the difference to cvodes on a few of them.

    python benchmarks/bench_exact.py                 # both parts
    python benchmarks/bench_exact.py --part forward
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def planar_spec(segments: int):
    from softpinn.symbolic.spec import spec_from_dict

    seg = {"length": 0.5, "mass": 0.5, "stiffness": [10.0, 10.0], "damping": [0.4, 0.4]}
    return spec_from_dict({"name": f"planar{segments}", "kind": "planar-pcc",
                           "gravity": [0.0, 9.81], "actuation": "none",
                           "segment": [seg] * segments}, source="benchmark")


def spatial_spec(segments: int):
    from softpinn.symbolic.spec import spec_from_dict

    seg = {"length": 0.2, "mass": 0.3, "radius": 0.0, "actuator_radius": 1.0,
           "stiffness": [1.0, 1.0, 1.0], "damping": [0.1, 0.1, 0.1]}
    return spec_from_dict({"name": f"spatial{segments}", "kind": "spatial-pcc",
                           "parameterization": "delta", "gravity": [0.0, 0.0, 9.81],
                           "actuation": "tip-wrench", "segment": [seg] * segments},
                          source="benchmark")


def _best(fn, repeat=5):
    fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_model(spec, batch: int, workdir: Path, speed: bool = True) -> dict:
    import casadi as ca
    import jax
    import numpy as np

    from softpinn.bridge.exact import jax_model
    from softpinn.symbolic import TrueModel, codegen

    n, m = spec.n, spec.m
    t0 = time.perf_counter()
    em = jax_model(spec)
    t_functions = time.perf_counter() - t0
    t0 = time.perf_counter()
    prog = em.program("forward")
    t_translate = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.3, 0.3, (n, batch))
    qd = rng.uniform(-0.2, 0.2, (n, batch))
    u = rng.uniform(-0.3, 0.3, (m, batch))
    # batch as the minor axis of every scalar operation (1.5x faster than the leading axis)
    fb = jax.jit(jax.vmap(lambda a, b, c: prog(a, b, c)[0], in_axes=1, out_axes=1))
    t0 = time.perf_counter()
    lowered = fb.lower(q, qd, u)
    t_trace = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiled = lowered.compile()
    t_compile = time.perf_counter() - t0
    res = {"model": spec.name, "n": n, "m": m, "batch": batch,
           "sx_instructions": prog.n_instructions, "functions_s": t_functions,
           "translate_s": t_translate, "trace_s": t_trace, "xla_compile_s": t_compile,
           "translate_and_compile_s": t_translate + t_trace + t_compile}
    if not speed:
        return res
    got = np.asarray(compiled(q, qd, u))
    res["jax_per_state_us"] = _best(lambda: compiled(q, qd, u).block_until_ready()) / batch * 1e6
    fwd = em.functions["forward"]
    cc = codegen.find_compiler()
    if cc:
        out = workdir / spec.name
        source = codegen.write_c({"forward": fwd}, out, "eom")
        codegen.compile_c(source, out / "eom.so", compiler=cc)
        fwd_c = codegen.load_external({"forward": fwd}, out / "eom.so")["forward"]
        fm = fwd_c.map(batch)
        args = [ca.DM(q), ca.DM(qd), ca.DM(u)]
        ref = np.asarray(fm(*args))
        res["c_map_per_state_us"] = _best(lambda: fm(*args)) / batch * 1e6
        res["jax_minus_c_max_abs"] = float(np.max(np.abs(got - ref)))
        res["jax_minus_c_max_rel"] = float(np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
    tm = TrueModel(spec)
    small = max(batch // 10, 1)
    qt, qdt, ut = q[:, :small].T.copy(), qd[:, :small].T.copy(), u[:, :small].T.copy()
    res["interpreter_truemodel_per_state_us"] = _best(lambda: tm.qdd(qt, qdt, ut), 2) / small * 1e6
    return res


def part_forward(args) -> dict:
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    import jax

    jax.config.update("jax_enable_x64", True)
    from softpinn.symbolic import load_spec

    out = {"threads": 1, "xla_flags": os.environ.get("XLA_FLAGS"), "jax": jax.__version__,
           "models": []}
    with tempfile.TemporaryDirectory() as tmp:
        for spec in (load_spec("task5"), planar_spec(1), planar_spec(2)):
            out["models"].append(bench_model(spec, args.batch, Path(tmp)))
        if args.segments:
            out["models"].append(bench_model(spatial_spec(args.segments), args.batch,
                                             Path(tmp), speed=False))
    return out


def part_simulate(args) -> dict:
    from concurrent.futures import ThreadPoolExecutor

    import jax
    import jax.numpy as jnp
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from softpinn.bridge.exact import jax_model
    from softpinn.bridge.exact.simulate import rk4_program
    from softpinn.symbolic import functions, load_spec
    from softpinn.symbolic.datasets import data_config, draw_trajectories
    from softpinn.symbolic.simulate import SimulationConfig, simulate

    spec = load_spec("task5")
    em = jax_model(spec)
    K = args.trajectories
    x0, sigs = draw_trajectories(data_config(spec), spec.n, spec.m, list(range(K)),
                                 duration=args.duration)
    cfg = SimulationConfig(integrator="rk4", duration=args.duration, rate=50.0, dt=args.dt)
    run = rk4_program(em, sigs[0], cfg)
    p = np.stack([s.params() for s in sigs], axis=1)
    halves = np.array_split(np.arange(K), 2)
    t0 = time.perf_counter()
    lowered = run.lower(jnp.asarray(x0[halves[0]].T), jnp.asarray(p[:, halves[0]]))
    compiled = lowered.compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        outs = list(pool.map(lambda h: np.asarray(compiled(jnp.asarray(x0[h].T),
                                                           jnp.asarray(p[:, h]))), halves))
    t_run = time.perf_counter() - t0
    x = np.concatenate(outs, axis=2).transpose(2, 0, 1)
    few = list(range(4))
    cv = simulate(functions(spec), x0[few], [sigs[i] for i in few],
                  SimulationConfig(integrator="cvodes", duration=args.duration, rate=50.0))
    return {"model": "task5", "trajectories": K, "duration_s": args.duration, "dt": args.dt,
            "steps": int(round(args.duration / args.dt)), "threads": 2,
            "compile_s": t_compile, "simulate_s": t_run, "total_s": t_compile + t_run,
            "finite": bool(np.all(np.isfinite(x))),
            "max_abs_diff_to_cvodes_4_trajectories": float(np.max(np.abs(x[few] - cv.x)))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("forward", "simulate", "all"), default="all")
    ap.add_argument("--batch", type=int, default=10_000)
    ap.add_argument("--segments", type=int, default=4, help="also time a spatial arm of this "
                    "many segments (translate + compile only; 0: none)")
    ap.add_argument("--trajectories", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--dt", type=float, default=0.001)
    args = ap.parse_args(argv)
    if args.part == "forward":
        print(json.dumps(part_forward(args), indent=1))
        return 0
    if args.part == "simulate":
        print(json.dumps(part_simulate(args), indent=1))
        return 0
    res = {}
    for part, flags in (("forward", ONE_THREAD), ("simulate", "")):
        env = dict(os.environ, XLA_FLAGS=flags)
        cmd = [sys.executable, __file__, "--part", part, "--batch", str(args.batch),
               "--segments", str(args.segments), "--trajectories", str(args.trajectories),
               "--duration", str(args.duration), "--dt", str(args.dt)]
        res[part] = json.loads(subprocess.run(cmd, env=env, capture_output=True, text=True,
                                              check=True).stdout)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
