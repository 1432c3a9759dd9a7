"""softpinn and its peers side by side: forward dynamics per state, one core, float64; prints
JSON whose headline is the ratio peer time ÷ softpinn time (above 1: softpinn is faster).

Peers (PyPI):

* jsrm 0.0.18: ``planar_pcs.factory`` on its shipped SymPy expressions, bend + axial strains per
  segment (n = 2 per segment, as softpinn's planar PCC), 1 and 2 segments; ``jit(vmap(ode))``.
* soromox 0.5.0: ``PCS`` of 2 links as task5 (length 0.2, mass 0.3 each): the two bending
  strains and the axial strain active (n = 6). soromox's rod axis is its local x (strain order
  [kappa_x, kappa_y, kappa_z, sigma_x, sigma_y, sigma_z], straight reference [0, 0, 0, 1, 0, 0]),
  so bending is kappa_y, kappa_z and elongation sigma_x, gravity along the rod; explicit
  diagonal stiffness 1 and damping 0.1 as task5; ``jit(vmap(forward_dynamics))``, at its
  default 5 Gauss points and at 10 (softpinn's quadrature order).

softpinn, on the same kinds of model (task5; planar PCC of 1 and 2 segments as
``bench_exact.planar_spec``): the batched C kernel as ``bench_exact.py --part forward`` times it
(``Kernel.nonzeros_soa``, inputs as struct of arrays), and the public call
``TrueModel.qdd(q, qd, u)`` on (N, n) arrays (which runs that kernel; the headline ratio).

How: by default ONE process (a virtual environment, created once, holding softpinn's checkout
``-e`` with the peers at softpinn's jax version) pinned to one core with XLA's single-thread
flags; every round calls all entries of a model alternately ``--reps`` times, the order rotated
from round to round, each call started once no other thread of the process uses CPU (XLA's
worker threads spin for ~10 ms after a call, see :func:`quiet`); per round the least process CPU
time (``time.process_time``, all threads) and the least wall time of each entry. The ratio of
a round is peer ÷ softpinn of that round's CPU times; the headline is the median over rounds
(min and max given). Where the versions do not allow one environment (``--mode processes``, or
automatically when it cannot be built), each library runs in its own environment, one process
per library and round, alternated, pinned to the same core (softpinn in the interpreter that
runs this script).

    python benchmarks/bench_peers.py [--batch 10000] [--rounds 3] [--reps 5] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
import venv
from pathlib import Path

ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
PEERS = {"jsrm": "jsrm==0.0.18", "soromox": "soromox==0.5.0"}
REPO = Path(__file__).resolve().parent.parent
#: model -> the peer timed beside softpinn on it
MODELS = {"planar1": "jsrm", "planar2": "jsrm", "task5": "soromox"}
#: softpinn's entries (on every model); the headline ratio divides by the first
SOFTPINN = ("softpinn_truemodel", "softpinn_kernel")
HEADLINE = "softpinn_truemodel"

# ---------------------------------------------------------------- entries (run in the worker)


def _states(n: int, m: int, batch: int):
    import numpy as np

    rng = np.random.default_rng(0)
    return (rng.uniform(-0.3, 0.3, (batch, n)), rng.uniform(-0.2, 0.2, (batch, n)),
            rng.uniform(-0.3, 0.3, (batch, m)))


def _spec(model: str):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_exact import planar_spec

    from softpinn.symbolic import load_spec

    return load_spec("task5") if model == "task5" else planar_spec(int(model[-1]))


def softpinn_entries(model: str, batch: int) -> dict:
    """name -> (call, info): TrueModel.qdd on (N, n) arrays and the kernel on SoA arrays."""
    import numpy as np

    from softpinn.symbolic import TrueModel
    from softpinn.symbolic.codegen import _kernel as kernel

    spec = _spec(model)
    tm = TrueModel(spec)
    q, qd, u = _states(spec.n, spec.m, batch)
    t0 = time.perf_counter()
    kf = kernel.kernels({"forward": tm.functions["forward"]})["forward"]
    build_s = time.perf_counter() - t0
    soa = [np.ascontiguousarray(a.T) for a in (q, qd, u)]
    out = {}
    out["softpinn_truemodel"] = (lambda: tm.qdd(q, qd, u),
                                 {"call": "TrueModel.qdd(q, qd, u), (N, n) arrays",
                                  "n": spec.n, "kernel_flags": list(kf.library.flags)})
    out["softpinn_kernel"] = (lambda: kf.nonzeros_soa(soa, batch),
                              {"call": "Kernel.nonzeros_soa, (n, N) arrays", "n": spec.n,
                               "build_or_load_s": build_s})
    ref = np.asarray(tm.qdd(q, qd, u))
    got = kf.nonzeros_soa(soa, batch)[0].T
    out["softpinn_kernel"][1]["equals_truemodel"] = bool(np.array_equal(ref, got))
    return out


def _jax_timed(fn, x):
    import jax
    import numpy as np

    t0 = time.perf_counter()
    c = jax.jit(jax.vmap(fn)).lower(x).compile()
    info = {"compile_s": time.perf_counter() - t0,
            "finite": bool(np.all(np.isfinite(np.asarray(c(x)))))}
    return (lambda: c(x).block_until_ready()), info


def jsrm_entries(model: str, batch: int) -> dict:
    import jax.numpy as jnp
    import jsrm
    from jsrm.integration import ode_factory
    from jsrm.systems import planar_pcs

    ns = int(model[-1])
    fp = Path(jsrm.__file__).parent / "symbolic_expressions" / f"planar_pcs_ns-{ns}.dill"
    t0 = time.perf_counter()
    B_xi, _fk, dyn, _aux = planar_pcs.factory(fp, strain_selector=jnp.array([True, False, True]
                                                                             * ns))
    load_s = time.perf_counter() - t0
    n = int(B_xi.shape[1])
    params = {"th0": jnp.array(0.0), "l": 0.5 * jnp.ones(ns), "r": 2e-2 * jnp.ones(ns),
              "rho": 1070 * jnp.ones(ns), "g": jnp.array([0.0, 9.81]),
              "E": 1e4 * jnp.ones(ns), "G": 1e3 * jnp.ones(ns), "D": 1e-3 * jnp.eye(3 * ns)}
    ode = ode_factory(dyn, params, jnp.zeros(n))
    q, qd, _ = _states(n, 0, batch)
    x = jnp.asarray(jnp.concatenate([q, qd], axis=1))
    call, info = _jax_timed(lambda xx: ode(0.0, xx), x)
    info.update(call=f"jit(vmap(ode)) of planar_pcs ns={ns}, bend + axial", n=n,
                version=jsrm.__version__, load_expressions_s=load_s)
    return {"jsrm": (call, info)}


def soromox_entries(model: str, batch: int) -> dict:
    import jax.numpy as jnp
    import soromox
    from soromox.systems import PCS, LinkSpec, PCSStructure

    ns = 2  # task5: two segments of length 0.2 and mass 0.3, radius 0.02 -> density
    length, mass, radius = 0.2, 0.3, 0.02
    density = mass / (jnp.pi * radius**2 * length)
    # local x is the rod axis: straight, unstretched reference [0, 0, 0, 1, 0, 0]
    links = [LinkSpec.circular(length=length, radius=radius, density=float(density),
                               reference_strain=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
                               stiffness=jnp.eye(6), damping=0.1 * jnp.eye(6))
             for _ in range(ns)]
    # bending kappa_y, kappa_z and axial stretch sigma_x of each link (task5's delta_x,
    # delta_y, delta_L); gravity along the rod (task5 hangs along its z)
    sel = jnp.array([False, True, True, True, False, False] * ns)
    n = int(sel.sum())
    q, qd, _ = _states(n, 0, batch)
    x = jnp.asarray(jnp.concatenate([q, qd], axis=1))
    out = {}
    for points in (5, 10):
        robot = PCS.from_links(links, gravity=jnp.array([9.81, 0.0, 0.0]),
                               structure=PCSStructure(strain_selector=sel,
                                                      num_gauss_points=points),
                               backend="jax")
        call, info = _jax_timed(lambda y, r=robot: r.forward_dynamics(0.0, y), x)
        info.update(call=f"jit(vmap(PCS.forward_dynamics)), {points} Gauss points"
                    + (" (soromox's default)" if points == 5 else ""), n=n,
                    version=getattr(soromox, "__version__", None))
        out[f"soromox_{points}pt"] = (call, info)
    return out


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def quiet(limit_s: float = 1.0) -> float:
    """Wait until no other thread of this process uses CPU (5 ms windows; at most
    ``limit_s``); returns the seconds waited. XLA's worker threads spin for some 10 ms after a
    call: timed in that window, softpinn's kernel right after a soromox call took 2.5 times its
    CPU time (those threads run on the same pinned core and count in the process's CPU time)."""
    t_start = time.perf_counter()
    while time.perf_counter() - t_start < limit_s:
        p0, t0 = time.process_time(), time.thread_time()
        time.sleep(0.005)
        if (time.process_time() - p0) - (time.thread_time() - t0) < 1e-4:
            break
    return time.perf_counter() - t_start


def worker(libraries: list[str], models: list[str], batch: int, rounds: int, reps: int,
           core: int, wait: bool = True) -> dict:
    """Time the entries of ``libraries`` on ``models`` in this process (pinned to ``core``):
    per model, ``rounds`` rounds of ``reps`` alternated calls, the order rotated per round."""
    os.sched_setaffinity(0, {core})
    import jax

    jax.config.update("jax_enable_x64", True)
    makers = {"softpinn": softpinn_entries, "jsrm": jsrm_entries, "soromox": soromox_entries}
    out = {"core": core, "pid": os.getpid(), "xla_flags": os.environ.get("XLA_FLAGS"),
           "jax": jax.__version__, "models": {}}
    for model in models:
        entries, info = {}, {}
        for lib in libraries:
            if lib != "softpinn" and lib != MODELS[model]:
                continue
            try:
                made = makers[lib](model, batch)
            except Exception as exc:  # a peer that does not run here is reported, not fatal
                info[lib] = {"error": f"{type(exc).__name__}: {exc}"[:800]}
                continue
            for name, (call, meta) in made.items():
                entries[name], info[name] = call, meta
        names = list(entries)
        for name in names:
            entries[name]()  # warm-up
        per_round, waited = [], 0.0
        for r in range(rounds):
            order = names[r % len(names):] + names[: r % len(names)] if names else []
            cpu = {k: float("inf") for k in order}
            wall = dict(cpu)
            for _ in range(reps):
                for name in order:
                    waited += quiet() if wait else 0.0
                    t0, c0 = time.perf_counter(), time.process_time()
                    entries[name]()
                    wall[name] = min(wall[name], time.perf_counter() - t0)
                    cpu[name] = min(cpu[name], time.process_time() - c0)
            per_round.append({"order": order,
                              "cpu_us_per_state": {k: v / batch * 1e6 for k, v in cpu.items()},
                              "wall_us_per_state": {k: v / batch * 1e6
                                                    for k, v in wall.items()}})
        out["models"][model] = {"entries": info, "rounds": per_round,
                                "quiet_wait_s": waited}
    out["xla_flags_after"] = os.environ.get("XLA_FLAGS")
    return out


# ---------------------------------------------------------------- environments and summary


def _env_python(root: Path, name: str, packages: list[str], probe: str) -> Path:
    """A virtual environment ``root/name`` in which ``probe`` runs (created and filled once)."""
    env = root / name
    py = env / "bin" / "python"
    if not py.exists():
        venv.create(env, with_pip=True)
    if subprocess.run([str(py), "-c", probe], capture_output=True).returncode != 0:
        subprocess.run([str(py), "-m", "pip", "install", "-q", *packages], check=True,
                       capture_output=True, text=True)
        if subprocess.run([str(py), "-c", probe], capture_output=True).returncode != 0:
            raise RuntimeError(f"{env}: '{probe}' fails after installing {packages}")
    return py


def together_python(root: Path) -> Path:
    """One environment with this checkout of softpinn (editable) and both peers, at softpinn's
    jax version (softpinn pins jax 0.10; both peers accept it)."""
    from importlib.metadata import version

    v = version("jax")
    probe = ("import jax, jsrm, soromox, softpinn, pathlib; "
             f"assert jax.__version__ == {v!r}; "
             "assert pathlib.Path(softpinn.__file__).resolve().parent == "
             f"pathlib.Path({str(REPO)!r})")
    return _env_python(root, "together", [*PEERS.values(), "-e", str(REPO), f"jax=={v}",
                                          f"jaxlib=={v}"], probe)


def _run_worker(py: Path, libraries, models, args, core: int, rounds: int) -> dict:
    cmd = [str(py), str(Path(__file__).resolve()), "--worker", "--libraries",
           ",".join(libraries), "--models", ",".join(models), "--batch", str(args.batch),
           "--rounds", str(rounds), "--reps", str(args.reps), "--core", str(core),
           *(["--no-wait"] if args.no_wait else [])]
    res = subprocess.run(cmd, capture_output=True, text=True,
                         env=dict(os.environ, XLA_FLAGS=ONE_THREAD))
    if res.returncode != 0:
        raise RuntimeError(res.stderr.strip()[-2000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def summarise(models: dict) -> dict:
    """Per model and entry: median / min CPU and wall µs per state over rounds; per peer
    entry: peer ÷ softpinn per round (CPU and wall), median, min, max."""
    out = {}
    for model, m in models.items():
        rounds = m["rounds"]
        names = sorted({k for r in rounds for k in r["cpu_us_per_state"]})
        times = {}
        for k in names:
            cpu = [r["cpu_us_per_state"][k] for r in rounds if k in r["cpu_us_per_state"]]
            wall = [r["wall_us_per_state"][k] for r in rounds if k in r["wall_us_per_state"]]
            times[k] = {"cpu_us_median": statistics.median(cpu), "cpu_us_min": min(cpu),
                        "wall_us_median": statistics.median(wall), "wall_us_min": min(wall)}
        ratios = {}
        for peer in (k for k in names if not k.startswith("softpinn")):
            for ref in SOFTPINN:
                both = [r for r in rounds if {peer, ref} <= set(r["cpu_us_per_state"])]
                rs = [r["cpu_us_per_state"][peer] / r["cpu_us_per_state"][ref] for r in both]
                ws = [r["wall_us_per_state"][peer] / r["wall_us_per_state"][ref] for r in both]
                if rs:
                    ratios[f"{peer}/{ref}"] = {
                        "cpu_median": statistics.median(rs), "cpu_min": min(rs),
                        "cpu_max": max(rs), "wall_median": statistics.median(ws)}
        headline = {k.split("/")[0]: v["cpu_median"] for k, v in ratios.items()
                    if k.endswith("/" + HEADLINE)}
        out[model] = {"peer_over_softpinn": headline, "ratios": ratios, "times": times,
                      "entries": m.get("entries", {})}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venvs", default=str(Path.home() / ".cache" / "softpinn-bench-peers"),
                    help="folder of the virtual environments (created if missing)")
    ap.add_argument("--mode", choices=("auto", "same-process", "processes"), default="auto")
    ap.add_argument("--batch", type=int, default=10_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--reps", type=int, default=5, help="alternated calls per entry and round")
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--out", default=None, help="also write the JSON here")
    ap.add_argument("--no-wait", action="store_true", help="start each timed call at once, "
                    "not once the process's other threads are idle (shows what XLA's spinning "
                    "threads do to the next call's time)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--libraries", default="softpinn,jsrm,soromox", help=argparse.SUPPRESS)
    ap.add_argument("--core", type=int, default=None, help="the core to pin to (default: the "
                    "first this process may use)")
    args = ap.parse_args(argv)
    core = args.core if args.core is not None else sorted(os.sched_getaffinity(0))[0]
    models = [m for m in args.models.split(",") if m]
    if args.worker:
        print(json.dumps(worker(args.libraries.split(","), models, args.batch, args.rounds,
                                args.reps, core, wait=not args.no_wait)))
        return 0
    root = Path(args.venvs)
    root.mkdir(parents=True, exist_ok=True)
    out = {"machine": {"cpu": _cpu_name(), "cores_online": os.cpu_count(),
                       "load_average_before": os.getloadavg()},
           "conditions": {"batch": args.batch, "rounds": args.rounds, "reps": args.reps,
                          "wait_for_idle_threads": not args.no_wait, "core": core,
                          "xla_flags": ONE_THREAD, "dtype": "float64",
                          "headline": f"median over rounds of peer CPU time ÷ {HEADLINE} CPU "
                          "time, same round"}}
    mode, py = args.mode, None
    if mode in ("auto", "same-process"):
        try:
            py = together_python(root)
            mode = "same-process"
        except (subprocess.CalledProcessError, RuntimeError) as exc:
            if mode == "same-process":
                raise
            out["same_process_unavailable"] = str(getattr(exc, "stderr", None) or exc)[-800:]
            mode = "processes"
    out["mode"] = mode
    t0 = time.perf_counter()
    if mode == "same-process":
        res = _run_worker(py, ["softpinn", "jsrm", "soromox"], models, args, core, args.rounds)
        out["worker"] = {k: v for k, v in res.items() if k != "models"}
        merged = res["models"]
    else:  # one process per library and round, alternated (order rotated), same core
        pys = {"softpinn": Path(sys.executable)}
        for name, req in PEERS.items():
            try:
                pys[name] = _env_python(root, name, [req], f"import {name}")
            except (subprocess.CalledProcessError, RuntimeError) as exc:
                out.setdefault("errors", {})[name] = str(getattr(exc, "stderr", None)
                                                         or exc)[-800:]
        merged = {m: {"entries": {}, "rounds": []} for m in models}
        libs = list(pys)
        for r in range(args.rounds):
            rnd = {m: {"order": [], "cpu_us_per_state": {}, "wall_us_per_state": {}}
                   for m in models}
            for lib in libs[r % len(libs):] + libs[: r % len(libs)]:
                mine = [m for m in models if lib == "softpinn" or MODELS[m] == lib]
                if not mine:
                    continue
                res = _run_worker(pys[lib], [lib], mine, args, core, 1)
                for m in mine:
                    got = res["models"][m]
                    merged[m]["entries"].update(got["entries"])
                    for key in ("cpu_us_per_state", "wall_us_per_state"):
                        rnd[m][key].update(got["rounds"][0][key])
                    rnd[m]["order"] += got["rounds"][0]["order"]
            for m in models:
                merged[m]["rounds"].append(rnd[m])
    out["seconds"] = time.perf_counter() - t0
    out["machine"]["load_average_after"] = os.getloadavg()
    out["models"] = summarise(merged)
    out["raw_rounds"] = {m: merged[m]["rounds"] for m in merged}
    text = json.dumps(out, indent=1)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
