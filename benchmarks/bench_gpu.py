"""The exact equations on a GPU: task5's forward dynamics and a batch of RK4 simulations, run by
the JAX replay of CasADi's instruction lists (:mod:`softpinn.learn._sx_replay`), which needs no
CasADi on the GPU machine. Prints JSON.

Two steps, because a GPU machine may have JAX but not CasADi:

    python benchmarks/bench_gpu.py prepare DIR   # here (CasADi): programs + reference values
    python benchmarks/bench_gpu.py run DIR       # there (JAX with a GPU): times and checks

``prepare`` writes ``DIR/forward.json`` and ``DIR/ode.json`` (task5's forward dynamics, eq. 4,
and its first-order field x' = f(x, u)), ``DIR/reference.npz``: random states (q = 0, where
theta = 0 of the delta parameterization, among them) with CasADi's q'' at them, and the
inputs of the simulations (task5's sinusoid ranges) with a JAX-on-CPU RK4 of the first two.

``run`` reports, in float64 (and float32 for the forward dynamics): the per-state time of
``jit(vmap(forward))`` for batches of 10^4 to 10^6 states (best of 5, after a compile), the
largest difference to CasADi at the reference states; and 1,000 (and 10,000) trajectories of
10 s of task5 at dt = 1 ms (10,000 RK4 steps, ``lax.scan`` over steps, ``vmap`` over
trajectories): compile and run times and the difference of the first two to the CPU reference.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

TASK = "task5"
DT, DURATION = 1e-3, 10.0


def prepare(out: Path) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from softpinn.bridge.exact.serialize import function_data
    from softpinn.symbolic import TrueModel
    from softpinn.symbolic.codegen._kernel_source import cuda_source
    from softpinn.symbolic.spec._spec import load_spec

    out.mkdir(parents=True, exist_ok=True)
    tm = TrueModel(TASK)
    for name, key in (("forward", "forward"), ("ode", "ode")):
        (out / f"{name}.json").write_text(json.dumps(function_data(tm.functions[key])))
    # the C kernel's straight-line code as a CUDA kernel, one thread per state (NVRTC there)
    (out / "forward.cu").write_text(cuda_source(tm.functions["forward"], "forward"))
    rng = np.random.default_rng(0)
    n, m = tm.n, tm.m
    q = rng.uniform(-0.3, 0.3, (64, n))
    q[:, [2, 5]] = rng.uniform(0.05, 0.2, (64, 2))  # elongations as in the task's data
    q[0] = 0.0
    qd, u = rng.uniform(-0.2, 0.2, (64, n)), rng.uniform(-1.0, 1.0, (64, m))
    qdd = np.asarray(tm.qdd(q, qd, u))
    data = load_spec(TASK).data
    k = 10_000  # the inputs of the largest simulation batch; smaller ones take the first
    lo = lambda key: np.asarray(data[f"{key}_low"], float)  # noqa: E731
    hi = lambda key: np.asarray(data[f"{key}_high"], float)  # noqa: E731
    sim = {"x0": np.concatenate([rng.uniform(lo("q0"), hi("q0"), (k, n)),
                                 rng.uniform(lo("qd0"), hi("qd0"), (k, n))], axis=1),
           "amp": rng.uniform(lo("amplitude"), hi("amplitude"), (k, m)),
           "freq": rng.uniform(lo("frequency"), hi("frequency"), (k, m)),
           "offset": rng.uniform(lo("offset"), hi("offset"), (k, m)),
           "phase": rng.uniform(0.0, 2 * np.pi, (k, m))}
    from softpinn.learn._sx_replay import ProgramFunction

    ode = ProgramFunction(json.loads((out / "ode.json").read_text()))
    t0 = time.perf_counter()
    xs = np.asarray(_simulate(ode, {key: v[:2] for key, v in sim.items()}))
    np.savez(out / "reference.npz", q=q, qd=qd, u=u, qdd=qdd, x_cpu=xs,
             **{f"sim_{key}": v for key, v in sim.items()})
    return {"task": TASK, "forward_instructions": len(json.loads(
        (out / "forward.json").read_text())["code"]), "cpu_reference_s": time.perf_counter() - t0}


def _simulate(ode, sim, dtype=None):
    """RK4 at DT over DURATION of the trajectories of ``sim`` (see :func:`sim_program`)."""
    import jax.numpy as jnp

    args = {k: jnp.asarray(v, dtype or jnp.float64) for k, v in sim.items()}
    return sim_program(ode)(args)


def sim_program(ode):
    """The jitted batch simulation: RK4 at DT over DURATION, inputs u = offset + amp sin(2 pi f
    t + phase) at each stage's time; takes the dict of :func:`prepare`'s ``sim`` arrays and
    returns the states at every 100th step, (K, samples, 2n)."""
    import jax
    import jax.numpy as jnp

    steps = int(round(DURATION / DT))

    def field(x, t, a):
        u = a["offset"] + a["amp"] * jnp.sin(2 * jnp.pi * a["freq"] * t + a["phase"])
        return ode(x, u)[0][:, 0]

    def one(a):
        def step(x, i):
            t = i * DT
            k1 = field(x, t, a)
            k2 = field(x + 0.5 * DT * k1, t + 0.5 * DT, a)
            k3 = field(x + 0.5 * DT * k2, t + 0.5 * DT, a)
            k4 = field(x + DT * k3, t + DT, a)
            return x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4), None

        def block(x, j):  # 100 steps, then keep the state
            x, _ = jax.lax.scan(step, x, j * 100 + jnp.arange(100))
            return x, x

        _, xs = jax.lax.scan(block, a["x0"], jnp.arange(steps // 100))
        return xs

    return jax.jit(jax.vmap(one))


SAVE: Path | None = None


def _save(res: dict) -> None:
    """The results so far, to --out (a run stopped at its time limit keeps what it measured)."""
    if SAVE is not None:
        SAVE.write_text(json.dumps(res, indent=1))


def _best(fn, repeat=5):
    fn().block_until_ready()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn().block_until_ready()
        times.append(time.perf_counter() - t0)
    return min(times)


def run_cuda(folder: Path, sizes, res: dict, blocks=(64, 128, 256),
             variants=((), ("-maxrregcount=128",))) -> None:
    """``forward.cu`` (:func:`softpinn.symbolic.codegen._kernel_source.cuda_source`) compiled by
    NVRTC through CuPy, one thread per state, float64: per-state time (best of 20 launches,
    CUDA events, after a warm-up) for each NVRTC option variant and block size, and the
    largest difference to CasADi."""
    import cupy as cp

    ref = np.load(folder / "reference.npz")
    n, m = ref["q"].shape[1], ref["u"].shape[1]
    source = (folder / "forward.cu").read_text()
    out: dict = {"variants": {}}
    rng = np.random.default_rng(1)
    data = {size: [rng.uniform(-0.2, 0.2, (size, k)) + (0.1 if k == n else 0)
                   for k in (n, n, m)] for size in sizes}

    def launcher(kernel, arrays, count, block):
        ins = [cp.ascontiguousarray(cp.asarray(a, cp.float64).T) for a in arrays]  # (k, N)
        res_ = cp.empty((n, count), cp.float64)
        argp = cp.asarray([a.data.ptr for a in ins], cp.uint64)
        resp = cp.asarray([res_.data.ptr], cp.uint64)
        grid = ((count + block - 1) // block,)

        def call():
            kernel(grid, (block,), (np.int64(count), np.int64(count), argp, resp))
        call.keep = (ins, argp, resp)
        return call, res_

    for options in variants:
        name = " ".join(options) or "default"
        t0 = time.perf_counter()
        kernel = cp.RawModule(code=source, options=("--std=c++17", *options)).get_function(
            "forward")
        row = {"compile_s": time.perf_counter() - t0,
               "registers": getattr(kernel, "num_regs", None),
               "local_bytes": getattr(kernel, "local_size_bytes", None)}
        call, got = launcher(kernel, [ref["q"], ref["qd"], ref["u"]], ref["q"].shape[0], 128)
        call()
        cp.cuda.Device().synchronize()
        got = cp.asnumpy(got).T
        row["max_rel_error_vs_casadi"] = float(np.abs(got - ref["qdd"]).max()
                                               / max(1.0, np.abs(ref["qdd"]).max()))
        for size in sizes:
            for block in blocks:
                call, _ = launcher(kernel, data[size], size, block)
                call()
                cp.cuda.Device().synchronize()
                start, stop = cp.cuda.Event(), cp.cuda.Event()
                best = float("inf")
                for _ in range(20):
                    start.record()
                    call()
                    stop.record()
                    stop.synchronize()
                    best = min(best, cp.cuda.get_elapsed_time(start, stop) / 1e3)
                row[f"{size}/{block}"] = {"best_s": best, "ns_per_state": 1e9 * best / size}
                print("cuda", name, size, block, row[f"{size}/{block}"], file=sys.stderr,
                      flush=True)
        out["variants"][name] = row
        res["cuda"] = out
        _save(res)
    for size in sizes:  # the best launch of each batch size
        rows = [(v[f"{size}/{b}"]["ns_per_state"], name, b) for name, v in out["variants"].items()
                for b in blocks]
        ns, name, b = min(rows)
        out[str(size)] = {"ns_per_state": ns, "variant": name, "block": b}
    res["cuda"] = out


def run(folder: Path, sizes=(10_000, 100_000, 1_000_000), counts=(1_000, 10_000),
        parts=("forward", "cuda", "simulate")) -> dict:
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from softpinn.learn._sx_replay import ProgramFunction

    ref = np.load(folder / "reference.npz")
    dev = jax.devices()[0]
    res = {"device": str(dev), "platform": dev.platform, "jax": jax.__version__,
           "forward": {}, "simulate": {}}
    if "cuda" in parts:
        try:
            run_cuda(folder, sizes, res)
        except ImportError as exc:
            res["cuda"] = {"error": f"no CuPy here ({exc})"}
    f = ProgramFunction(json.loads((folder / "forward.json").read_text()))
    n, m = ref["q"].shape[1], ref["u"].shape[1]
    for dtype in (jnp.float64, jnp.float32) if "forward" in parts else ():
        fwd = jax.jit(jax.vmap(lambda q, qd, u: f(q, qd, u)[0][:, 0]))
        got = np.asarray(fwd(*(jnp.asarray(ref[k], dtype) for k in ("q", "qd", "u"))))
        err = float(np.abs(got - ref["qdd"]).max() / max(1.0, np.abs(ref["qdd"]).max()))
        rows = {"max_rel_error_vs_casadi": err}
        rng = np.random.default_rng(1)
        for size in sizes:
            args = [jnp.asarray(rng.uniform(-0.2, 0.2, (size, k)) + (0.1 if k == n else 0),
                                dtype) for k in (n, n, m)]
            t0 = time.perf_counter()
            compiled = fwd.lower(*args).compile()
            compile_s = time.perf_counter() - t0
            best = _best(lambda a=args, g=compiled: g(*a))
            rows[str(size)] = {"compile_s": compile_s, "best_s": best,
                               "ns_per_state": 1e9 * best / size}
            res["forward"][jnp.dtype(dtype).name] = rows
            _save(res)
            print(dtype.__name__ if hasattr(dtype, "__name__") else dtype, size, rows[str(size)],
                  file=sys.stderr, flush=True)
        res["forward"][jnp.dtype(dtype).name] = rows
    ode = ProgramFunction(json.loads((folder / "ode.json").read_text()))
    sim = {k[4:]: ref[k] for k in ref.files if k.startswith("sim_")}
    program = sim_program(ode)
    for count in counts if "simulate" in parts else ():
        part = {k: jnp.asarray(v[:count], jnp.float64) for k, v in sim.items()}
        t0 = time.perf_counter()
        compiled = program.lower(part).compile()
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(2):
            t0 = time.perf_counter()
            xs = compiled(part)
            xs.block_until_ready()
            times.append(time.perf_counter() - t0)
        xs = np.asarray(xs)
        diff = float(np.abs(xs[:2] - ref["x_cpu"]).max())
        res["simulate"][str(count)] = {
            "trajectories": count, "duration_s": DURATION, "dt": DT,
            "steps": int(round(DURATION / DT)), "compile_s": compile_s, "run_s": times,
            # fixed-step RK4 at 1 ms leaves some of these random drives (the arm swung far,
            # into stiffer states): counted, not hidden
            "finite_trajectories": int(np.isfinite(xs).all(axis=(1, 2)).sum()),
            "max_abs_diff_first_two_vs_cpu": diff}
        print(count, res["simulate"][str(count)], file=sys.stderr, flush=True)
        _save(res)
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("step", choices=("prepare", "run"))
    p.add_argument("folder", type=Path)
    p.add_argument("--out", type=Path, help="also write the JSON here")
    p.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000],
                   help="batch sizes of the forward dynamics (run)")
    p.add_argument("--trajectories", type=int, nargs="*", default=[1_000, 10_000],
                   help="simulation batch sizes (run; at most 10,000)")
    p.add_argument("--parts", nargs="+", choices=("forward", "cuda", "simulate"),
                   default=["forward", "cuda", "simulate"],
                   help="run: the JAX replay's forward dynamics, the CUDA kernel (CuPy), the "
                        "JAX simulations")
    a = p.parse_args(argv)
    global SAVE
    SAVE = a.out
    res = (prepare(a.folder) if a.step == "prepare"
           else run(a.folder, tuple(a.sizes), tuple(a.trajectories), tuple(a.parts)))
    text = json.dumps(res, indent=1)
    print(text)
    if a.out:
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
