"""Benchmark of the symbolic side: derive, functions, C generation and compilation, forward
dynamics per call (virtual machine, compiled, batched), and simulating task 5.

Prints one JSON object to stdout. Usage::

    python benchmarks/bench_symbolic.py [--segments 1 2 3 4] [--batch 10000] [--quick]

Spatial arms of S segments use the task 4 segment (delta parameterization, tip-wrench
actuation). Times are wall-clock seconds on this machine (``os.cpu_count()`` is recorded);
the C code is compiled fresh into a temporary directory (no cache).
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

import casadi as ca
import numpy as np

from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.codegen._generate import expression_sizes
from softpinn.symbolic.derivation._eom import derive
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._signals import Zero, sample_signal
from softpinn.symbolic.simulation._simulate import SimulationConfig, simulate
from softpinn.symbolic.spec._spec import load_spec, spec_from_dict


def arm_spec(segments: int, tag: str):
    seg = {
        "length": 0.2,
        "mass": 0.3,
        "radius": 0.0,
        "actuator_radius": 1.0,
        "stiffness": [1.0, 1.0, 1.0],
        "damping": [0.1, 0.1, 0.1],
    }
    return spec_from_dict(
        {
            "name": f"bench{segments}_{tag}",
            "kind": "spatial-pcc",
            "parameterization": "delta",
            "gravity": [0.0, 0.0, 9.81],
            "actuation": "tip-wrench",
            "segment": [seg] * segments,
        },
        source="benchmark",
    )


def per_call(fn: ca.Function, args, repeat: int) -> float:
    """Seconds per call of ``fn`` from Python with DM arguments (includes call overhead)."""
    dm = [ca.DM(a) for a in args]
    fn(*dm)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn(*dm)
        best = min(best, (time.perf_counter() - t0) / repeat)
    return best


def batched_per_state(
    fn: ca.Function, args, batch: int, parallel: str = "serial", threads: int = 1
) -> float:
    fm = fn.map(batch, parallel, threads) if parallel != "serial" else fn.map(batch)
    ins = [ca.DM(np.tile(np.asarray(a, dtype=float).reshape(-1, 1), (1, batch))) for a in args]
    fm(*ins)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        fm(*ins)
        best = min(best, time.perf_counter() - t0)
    return best / batch


def bench_arm(segments: int, batch: int, workdir: Path) -> dict:
    tag = f"{os.getpid()}_{time.time_ns()}"
    spec = arm_spec(segments, tag)
    t0 = time.perf_counter()
    derive(spec)
    t_derive = time.perf_counter() - t0
    t0 = time.perf_counter()
    fns = functions(spec)
    t_functions = time.perf_counter() - t0
    out = workdir / f"arm{segments}"
    t0 = time.perf_counter()
    source = codegen.write_c(fns, out, "eom")
    t_gen = time.perf_counter() - t0
    cc = codegen.find_compiler()
    t_compile = codegen.compile_c(source, out / "eom.so", compiler=cc) if cc else None
    ext = codegen.load_external(fns, out / "eom.so") if cc else {}
    n, m = spec.n, spec.m
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, n)
    q[2::3] = rng.uniform(0.0, 0.1, segments)
    qd = rng.uniform(-0.2, 0.2, n)
    u = rng.uniform(-0.3, 0.3, m)
    fwd, fwd_c = fns["forward"], ext.get("forward")
    args = [q, qd, u]
    err = float(np.max(np.abs(np.asarray(fwd_c(*args)) - np.asarray(fwd(*args))))) if cc else None
    res = {
        "segments": segments,
        "n": n,
        "m": m,
        "derive_s": t_derive,
        "functions_s": t_functions,
        "generate_c_s": t_gen,
        "compile_s": t_compile,
        "derive_and_compile_s": t_derive + t_functions + t_gen + (t_compile or 0.0),
        "c_source_bytes": source.stat().st_size,
        "forward_size": expression_sizes(fwd),
        "ode_size": expression_sizes(fns["ode"]),
        "forward_compiled_vs_vm_max_abs_diff": err,
        "forward_vm_per_call_us": per_call(fwd, args, 200) * 1e6,
        "forward_compiled_per_call_us": per_call(fwd_c, args, 2000) * 1e6 if cc else None,
        f"forward_vm_batched_{batch}_per_state_us": batched_per_state(
            fwd, args, max(batch // 10, 1)
        )
        * 1e6,
        f"forward_compiled_batched_{batch}_per_state_us": batched_per_state(fwd_c, args, batch)
        * 1e6
        if cc
        else None,
        f"forward_compiled_batched_{batch}_threads2_per_state_us": batched_per_state(
            fwd_c, args, batch, "thread", 2
        )
        * 1e6
        if cc
        else None,
    }
    return res


def bench_simulation(duration: float, rate: float, workdir: Path) -> dict:
    spec = load_spec("task5")
    fns = codegen.compile_functions(functions(spec), directory=workdir / "cache").functions
    rng = np.random.default_rng(5)
    x0 = np.concatenate([[0.3, -0.2, 0.05, -0.1, 0.2, 0.02], rng.uniform(-0.1, 0.1, 6)])[None]
    data = dict(spec.data)
    ranges = {
        k: v
        for k, v in data.items()
        if k.split("_")[0] in ("amplitude", "offset", "frequency", "phase")
    }
    sig = sample_signal("sinusoid", 6, rng, ranges)
    out = {"model": "task5", "duration_s": duration, "rate_hz": rate}
    for label, cfg in (
        ("cvodes_tol1e-10", SimulationConfig(duration=duration, rate=rate, threads=1)),
        (
            "cvodes_tol1e-8",
            SimulationConfig(duration=duration, rate=rate, rtol=1e-8, atol=1e-8, threads=1),
        ),
    ):
        t0 = time.perf_counter()
        r = simulate(fns, x0, [sig], cfg)
        out[label] = {
            "total_s": time.perf_counter() - t0,
            "integrate_s": r.info["integrate_seconds"],
            "postprocess_s": r.info["postprocess_seconds"],
            "samples": int(r.x.shape[1]),
        }
    # two trajectories at once with 2 threads
    cfg = SimulationConfig(duration=duration, rate=rate, threads=2)
    t0 = time.perf_counter()
    simulate(fns, np.vstack([x0, x0 * 0.5]), [sig, Zero(6)], cfg)
    out["cvodes_tol1e-10_2traj_2threads_total_s"] = time.perf_counter() - t0
    # fixed-step RK4 at the paper's dt = 0.0002 s, 1 kHz output, over a tenth of the duration
    short = duration / 10
    cfg = SimulationConfig(integrator="rk4", duration=short, rate=rate, dt=0.0002, threads=1)
    t0 = time.perf_counter()
    r = simulate(fns, x0, [sig], cfg)
    out["rk4_dt2e-4"] = {
        "duration_s": short,
        "total_s": time.perf_counter() - t0,
        "integrate_s": r.info["integrate_seconds"],
        "steps": int(round(short / 0.0002)),
    }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--batch", type=int, default=10000)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="segments 1 2, batch 1000, 6 s")
    args = ap.parse_args(argv)
    if args.quick:
        args.segments, args.batch, args.duration = [1, 2], 1000, 6.0
    with tempfile.TemporaryDirectory(prefix="bench-symbolic-") as tmp:
        work = Path(tmp)
        arms = []
        for s in args.segments:
            print(f"arm with {s} segment(s) ...", file=sys.stderr)
            arms.append(bench_arm(s, args.batch, work))
        print("simulation ...", file=sys.stderr)
        sim = bench_simulation(args.duration, 1000.0, work)
    result = {
        "benchmark": "symbolic",
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "casadi": ca.__version__,
            "compiler": codegen.find_compiler(),
            "flags": list(codegen.DEFAULT_FLAGS),
            "load_average": os.getloadavg(),
        },
        "arms": arms,
        "simulation": sim,
    }
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
