"""Benchmark the exact model in JAX (softpinn.bridge.exact) against CasADi; prints JSON.

Parts (each in its own process; every part, run alone or with the others, sets XLA's
single-thread flags before jax is imported: one thread per XLA call):

* ``forward``: forward dynamics per state for task5 (two spatial segments, n = 6) and planar
  PCC arms of 1 and 2 segments, batch 10,000, float64, on ONE core (``sched_setaffinity`` and
  XLA's single-thread flags): CasADi's interpreter (``TrueModel.qdd`` batched), CasADi's
  compiled C with ``map`` (serial), the JAX translation (``jit(vmap)``); translate, trace and
  XLA-compile times; the batched C kernel of :mod:`softpinn.symbolic.codegen._kernel` (build
  time in a fresh cache, per-state time), ``TrueModel.qdd`` on the batch (the kernel); the
  largest differences, and the errors of the kernel and of CasADi's interpreter against the
  Function evaluated in long double (:func:`accuracy`). ``--segments 4`` adds a 4-segment arm
  (kernel build, speed and accuracy; XLA with ``--xla-segments``).
* ``simulate``: 1,000 trajectories of 10 s of task5 with fixed-step RK4 on two cores: the
  batched C kernels (``bridge.exact.simulate`` backend ``"c"``, compiled into a fresh cache)
  and JAX (two halves run concurrently); the difference to cvodes on a few of them.

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


def with_one_thread(flags: str | None) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with XLA's single-thread settings (replacing any other
    value given for them). Every part sets them before it imports jax: one XLA call runs on one
    thread (the simulate part runs two calls at once, on two threads)."""
    ours = ONE_THREAD.split()
    keys = {w.split("=", 1)[0] for w in ours}
    return " ".join([w for w in (flags or "").split() if w.split("=", 1)[0] not in keys] + ours)


def planar_spec(segments: int):
    from softpinn.symbolic.spec._spec import spec_from_dict

    seg = {"length": 0.5, "mass": 0.5, "stiffness": [10.0, 10.0], "damping": [0.4, 0.4]}
    return spec_from_dict({"name": f"planar{segments}", "kind": "planar-pcc",
                           "gravity": [0.0, 9.81], "actuation": "none",
                           "segment": [seg] * segments}, source="benchmark")


def spatial_spec(segments: int):
    from softpinn.symbolic.spec._spec import spec_from_dict

    seg = {"length": 0.2, "mass": 0.3, "radius": 0.0, "actuator_radius": 1.0,
           "stiffness": [1.0, 1.0, 1.0], "damping": [0.1, 0.1, 0.1]}
    return spec_from_dict({"name": f"spatial{segments}", "kind": "spatial-pcc",
                           "parameterization": "delta", "gravity": [0.0, 0.0, 9.81],
                           "actuation": "tip-wrench", "segment": [seg] * segments},
                          source="benchmark")


CPU = {}  # per _best label: the least process CPU time of a call (robust to other load)


def _best(fn, repeat=5, label=None):
    """Least wall time of ``repeat`` calls (after one warm-up); with ``label`` the least
    process CPU time too (in CPU[label]): on shared cores the wall time includes waiting."""
    fn()
    best = cpu = float("inf")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    if label is not None:
        CPU[label] = cpu
    return best


def accuracy(fwd, args, kout) -> dict:
    """Per-state relative errors (max |x - exact| / max |exact| over a state's q̈) of the kernel
    and of CasADi's interpreter against the same Function in extended precision
    (``symbolic.codegen._extended``): which of the two double-precision paths is closer to the
    exact value, where they differ (ill-conditioned states)."""
    import numpy as np

    from softpinn.symbolic.codegen import _extended

    if not _extended.available():
        return {"extended": "unavailable (no compiler, or long double is a double)"}
    exact = _extended.extended(fwd, *args)[0]
    casadi = np.asarray(fwd.map(exact.shape[1])(*args))
    scale = np.max(np.abs(exact), axis=0)
    out = {"extended": f"long double, {np.finfo(np.longdouble).nmant + 1}-bit significand"}
    for name, x in (("kernel", kout), ("casadi", casadi)):
        err = (np.max(np.abs(x - exact), axis=0) / scale).astype(np.float64)
        out[f"{name}_vs_extended_max_rel"] = float(err.max())
        out[f"{name}_vs_extended_p99_rel"] = float(np.quantile(err, 0.99))
    diff = np.max(np.abs(kout - casadi), axis=0) / np.max(np.abs(casadi), axis=0)
    out["kernel_minus_casadi_max_rel"] = float(diff.max())
    out["kernel_minus_casadi_above_1e-13"] = int(np.sum(diff > 1e-13))
    return out


def bench_model(spec, batch: int, workdir: Path, speed: bool = True, xla: bool = True) -> dict:
    import casadi as ca
    import jax
    import numpy as np

    from softpinn.bridge.exact import jax_model
    from softpinn.symbolic import TrueModel
    from softpinn.symbolic.codegen import _codegen as codegen

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
    res = {"model": spec.name, "n": n, "m": m, "batch": batch,
           "sx_instructions": prog.n_instructions, "functions_s": t_functions,
           "translate_s": t_translate}
    got = None
    if xla:
        # batch as the minor axis of every scalar operation (1.5x faster than the leading axis)
        fb = jax.jit(jax.vmap(lambda a, b, c: prog(a, b, c)[0], in_axes=1, out_axes=1))
        t0 = time.perf_counter()
        lowered = fb.lower(q, qd, u)
        t_trace = time.perf_counter() - t0
        t0 = time.perf_counter()
        compiled = lowered.compile()
        t_compile = time.perf_counter() - t0
        res.update(trace_s=t_trace, xla_compile_s=t_compile,
                   translate_and_compile_s=t_translate + t_trace + t_compile)
        got = np.asarray(compiled(q, qd, u))
        res["jax_per_state_us"] = _best(lambda: compiled(q, qd, u).block_until_ready(),
                                        label="jax") / batch * 1e6
        res["jax_cpu_per_state_us"] = CPU["jax"] / batch * 1e6
    fwd = em.functions["forward"]
    # the batched C kernel (symbolic.codegen._kernel): generate, compile (fresh cache), run, 1 core
    from softpinn.symbolic.codegen import _kernel as kernel

    t0 = time.perf_counter()
    ks = kernel.kernels({"forward": fwd}, directory=workdir / f"kcache_{spec.name}")
    res["kernel_build_s"] = time.perf_counter() - t0
    if ks is not None:
        kf = ks["forward"]
        res["kernel_flags"] = list(kf.library.flags)
        res["kernel_compile_s"] = kf.library.compile_seconds
        res["functions_and_kernel_s"] = t_functions + res["kernel_build_s"]
        kin = [np.ascontiguousarray(q), np.ascontiguousarray(qd), np.ascontiguousarray(u)]
        kout = kf.nonzeros_soa(kin, batch)[0]
        res["kernel_per_state_us"] = _best(lambda: kf.nonzeros_soa(kin, batch),
                                           label="kernel") / batch * 1e6
        res["kernel_cpu_per_state_us"] = CPU["kernel"] / batch * 1e6
        if got is not None:
            res["kernel_minus_jax_max_rel"] = float(np.max(np.abs(kout - got))
                                                    / np.max(np.abs(got)))
        res.update(accuracy(fwd, (q, qd, u), kout))
    if not speed:
        return res
    cc = codegen.find_compiler()
    if cc:
        out = workdir / spec.name
        source = codegen.write_c({"forward": fwd}, out, "eom")
        codegen.compile_c(source, out / "eom.so", compiler=cc)
        fwd_c = codegen.load_external({"forward": fwd}, out / "eom.so")["forward"]
        fm = fwd_c.map(batch)
        args = [ca.DM(q), ca.DM(qd), ca.DM(u)]
        ref = np.asarray(fm(*args))
        res["c_map_per_state_us"] = _best(lambda: fm(*args), label="c") / batch * 1e6
        res["c_map_cpu_per_state_us"] = CPU["c"] / batch * 1e6
        res["jax_minus_c_max_abs"] = float(np.max(np.abs(got - ref)))
        res["jax_minus_c_max_rel"] = float(np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
        if ks is not None:
            res["kernel_minus_c_max_rel"] = float(np.max(np.abs(kout - ref))
                                                  / np.max(np.abs(ref)))
    tm = TrueModel(spec, compiled=False)
    small = max(batch // 10, 1)
    qt, qdt, ut = q[:, :small].T.copy(), qd[:, :small].T.copy(), u[:, :small].T.copy()
    res["interpreter_truemodel_per_state_us"] = _best(lambda: tm.qdd(qt, qdt, ut), 2) / small * 1e6
    tm = TrueModel(spec)  # batched calls: the kernel (compiled into the default cache)
    qb, qdb, ub = q.T.copy(), qd.T.copy(), u.T.copy()
    res["truemodel_batched_per_state_us"] = _best(lambda: tm.qdd(qb, qdb, ub)) / batch * 1e6
    res["truemodel_batched_path"] = "kernel" if tm._kernels.get("forward") else "casadi"
    return res


def part_forward(args) -> dict:
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    import jax

    jax.config.update("jax_enable_x64", True)
    from softpinn.symbolic import load_spec

    out = {"threads": 1, "xla_flags": os.environ.get("XLA_FLAGS"), "jax": jax.__version__,
           "load_average_before": os.getloadavg(), "models": []}
    with tempfile.TemporaryDirectory() as tmp:
        for spec in (load_spec("task5"), planar_spec(1), planar_spec(2)):
            out["models"].append(bench_model(spec, args.batch, Path(tmp)))
        if args.segments:
            out["models"].append(bench_model(spatial_spec(args.segments), args.batch,
                                             Path(tmp), speed=False, xla=args.xla_segments))
    out["load_average_after"] = os.getloadavg()
    return out


def part_simulate(args) -> dict:
    from concurrent.futures import ThreadPoolExecutor

    import jax
    import jax.numpy as jnp
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from softpinn.bridge.exact import jax_model
    from softpinn.bridge.exact.simulate import rk4_program
    from softpinn.symbolic import load_spec
    from softpinn.symbolic.model import _functions as functions
    from softpinn.symbolic.simulation._datasets import data_config, draw_trajectories
    from softpinn.symbolic.simulation._simulate import SimulationConfig, simulate

    spec = load_spec("task5")
    em = jax_model(spec)
    K = args.trajectories
    x0, sigs = draw_trajectories(data_config(spec), spec.n, spec.m, list(range(K)),
                                 duration=args.duration)
    cfg = SimulationConfig(integrator="rk4", duration=args.duration, rate=50.0, dt=args.dt,
                           threads=2)
    few = list(range(4))
    cv = simulate(functions(spec), x0[few], [sigs[i] for i in few],
                  SimulationConfig(integrator="cvodes", duration=args.duration, rate=50.0))
    out = {"model": "task5", "trajectories": K, "duration_s": args.duration, "dt": args.dt,
           "steps": int(round(args.duration / args.dt)), "threads": 2,
           "xla_flags": os.environ.get("XLA_FLAGS"),
           "load_average_before": os.getloadavg()}
    xc = None
    if "c" in args.sim_backends:
        # the batched C kernels through the user path (bridge.exact.simulate, backend "c"):
        # compile into a fresh cache, RK4 in C on 2 threads, then qdd, p, M and the checks
        from softpinn.bridge.exact import simulate as exact_simulate

        with tempfile.TemporaryDirectory() as cache:
            os.environ["SOFTPINN_CACHE"] = cache
            t0 = time.perf_counter()
            res = exact_simulate(em, x0, sigs, cfg, backend="c")
            total = time.perf_counter() - t0
            # again from the cache: the run alone, wall and process CPU (2 threads)
            t0, c0 = time.perf_counter(), time.process_time()
            again = exact_simulate(em, x0, sigs, cfg, backend="c")
            rerun_s, rerun_cpu = time.perf_counter() - t0, time.process_time() - c0
        xc = res.x
        out["c"] = {"total_s": total, "compile_s": res.info["compile_seconds"],
                    "cached_rerun_s": rerun_s, "cached_rerun_cpu_s": rerun_cpu,
                    "cached_rerun_integrate_s": again.info["integrate_seconds"],
                    "rerun_identical": bool(np.array_equal(again.x, res.x)),
                    "integrate_s": res.info["integrate_seconds"] - res.info["compile_seconds"],
                    "postprocess_s": res.info["postprocess_seconds"],
                    "flags": res.info.get("compiler_flags"),
                    "finite": bool(np.all(np.isfinite(xc))),
                    "max_abs_diff_to_cvodes_4_trajectories": float(np.max(np.abs(xc[few]
                                                                                 - cv.x)))}
        out["load_average_after_c"] = os.getloadavg()
    if "jax" not in args.sim_backends:
        return out
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
    out["jax"] = {"compile_s": t_compile, "simulate_s": t_run, "total_s": t_compile + t_run,
                  "finite": bool(np.all(np.isfinite(x))),
                  "max_abs_diff_to_cvodes_4_trajectories": float(np.max(np.abs(x[few]
                                                                               - cv.x)))}
    if xc is not None:
        out["max_abs_diff_c_to_jax_all"] = float(np.max(np.abs(xc - x)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("forward", "simulate", "all"), default="all")
    ap.add_argument("--batch", type=int, default=10_000)
    ap.add_argument("--segments", type=int, default=4, help="also time a spatial arm of this "
                    "many segments (translate + compile only; 0: none)")
    ap.add_argument("--xla-segments", action="store_true", help="also XLA-compile the "
                    "--segments arm (minutes: 167 s for 4 segments)")
    ap.add_argument("--trajectories", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--dt", type=float, default=0.001)
    ap.add_argument("--sim-backends", default="c,jax", help="simulate part: c, jax or both")
    args = ap.parse_args(argv)
    if "jax" in sys.modules:
        raise SystemExit("bench_exact: jax was imported before XLA's thread flags were set")
    os.environ["XLA_FLAGS"] = with_one_thread(os.environ.get("XLA_FLAGS"))
    if args.part == "forward":
        print(json.dumps(part_forward(args), indent=1))
        return 0
    if args.part == "simulate":
        print(json.dumps(part_simulate(args), indent=1))
        return 0
    res = {}
    for part in ("forward", "simulate"):
        env = dict(os.environ)  # with the single-thread flags (above)
        cmd = [sys.executable, __file__, "--part", part, "--batch", str(args.batch),
               "--segments", str(args.segments), "--trajectories", str(args.trajectories),
               *(["--xla-segments"] if args.xla_segments else []),
               "--sim-backends", args.sim_backends,
               "--duration", str(args.duration), "--dt", str(args.dt)]
        res[part] = json.loads(subprocess.run(cmd, env=env, capture_output=True, text=True,
                                              check=True).stdout)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
