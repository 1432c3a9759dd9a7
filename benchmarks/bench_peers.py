"""Peers side by side: jsrm (planar PCS) and soromox (spatial PCS) forward dynamics per state,
each in its own virtual environment created by this script (they may pin other jax versions);
prints JSON. Compare with ``benchmarks/bench_exact.py --part forward`` (softpinn's JAX
translation and compiled C on the same kinds of model, same batch, one core).

* jsrm 0.0.18 (PyPI): ``planar_pcs.factory`` on its shipped SymPy expressions, bend + axial
  strains per segment (n = 2 per segment, as softpinn's planar PCC), 1 and 2 segments;
  ``jit(vmap(ode_fn))``.
* soromox 0.5.0 (PyPI): ``PCS`` of 2 circular links with the bending and elongation strains
  active (n = 6, as task5), JAX backend, ``jit(vmap(forward_dynamics))``.

Both: float64, batch 10,000, one core (``taskset`` + XLA's single-thread flags). A peer that
cannot be installed here is reported as ``{"error": ...}``.

    python benchmarks/bench_peers.py [--venvs DIR] [--batch 10000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import venv
from pathlib import Path

ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
PEERS = {"jsrm": "jsrm==0.0.18", "soromox": "soromox==0.5.0"}

COMMON = r'''
import json, os, sys, time
os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
BATCH = int(sys.argv[1])

def timed(fn, x):
    t0 = time.perf_counter(); c = jax.jit(jax.vmap(fn)).lower(x).compile()
    compile_s = time.perf_counter() - t0
    c(x).block_until_ready()
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter(); c(x).block_until_ready()
        best = min(best, time.perf_counter() - t0)
    return {"compile_s": compile_s, "per_state_us": best / x.shape[0] * 1e6,
            "finite": bool(np.all(np.isfinite(np.asarray(c(x)))))}
'''

JSRM = COMMON + r'''
from pathlib import Path
import jsrm
from jsrm.integration import ode_factory
from jsrm.systems import planar_pcs
out = {"version": jsrm.__version__, "jax": jax.__version__, "models": []}
for ns in (1, 2):
    fp = Path(jsrm.__file__).parent / "symbolic_expressions" / f"planar_pcs_ns-{ns}.dill"
    t0 = time.perf_counter()
    sel = jnp.array([True, False, True] * ns)
    B_xi, fk, dyn, aux = planar_pcs.factory(fp, strain_selector=sel)
    load_s = time.perf_counter() - t0
    n = int(B_xi.shape[1])
    params = {"th0": jnp.array(0.0), "l": 0.5 * jnp.ones(ns), "r": 2e-2 * jnp.ones(ns),
              "rho": 1070 * jnp.ones(ns), "g": jnp.array([0.0, 9.81]),
              "E": 1e4 * jnp.ones(ns), "G": 1e3 * jnp.ones(ns), "D": 1e-3 * jnp.eye(3 * ns)}
    ode = ode_factory(dyn, params, jnp.zeros(n))
    rng = np.random.default_rng(0)
    x = jnp.asarray(np.concatenate([rng.uniform(-0.3, 0.3, (BATCH, n)),
                                    rng.uniform(-0.2, 0.2, (BATCH, n))], axis=1))
    res = timed(lambda xx: ode(0.0, xx), x)
    out["models"].append({"model": f"jsrm planar_pcs ns={ns}", "segments": ns, "n": n,
                          "load_expressions_s": load_s, **res})
print(json.dumps(out))
'''

SOROMOX = COMMON + r'''
import soromox
from soromox.systems import PCS, LinkSpec, PCSStructure
out = {"version": getattr(soromox, "__version__", None), "jax": jax.__version__, "models": []}
ns = 2
links = [LinkSpec.circular(length=0.2, radius=0.02, density=1070.0,
                           reference_strain=[0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                           young_modulus=2e3, shear_modulus=1e3,
                           material_damping_coefficient=362.0) for _ in range(ns)]
sel = jnp.array([True, True, False, False, False, True] * ns)
robot = PCS.from_links(links, gravity=jnp.array([0.0, 0.0, 9.81]),
                       structure=PCSStructure(strain_selector=sel), backend="jax")
n = int(sel.sum())
rng = np.random.default_rng(0)
x = jnp.asarray(np.concatenate([rng.uniform(-0.3, 0.3, (BATCH, n)),
                                rng.uniform(-0.2, 0.2, (BATCH, n))], axis=1))
res = timed(lambda y: robot.forward_dynamics(0.0, y), x)
out["models"].append({"model": "soromox PCS 2 segments, spatial", "segments": ns, "n": n,
                      **res})
print(json.dumps(out))
'''


def ensure_venv(root: Path, name: str) -> Path:
    """A virtual environment with the peer installed (created once, then reused)."""
    env = root / name
    py = env / "bin" / "python"
    if not py.exists():
        venv.create(env, with_pip=True)
    probe = subprocess.run([str(py), "-c", f"import {name}"], capture_output=True)
    if probe.returncode != 0:
        subprocess.run([str(py), "-m", "pip", "install", "-q", PEERS[name]], check=True,
                       capture_output=True, text=True)
    return py


def run_peer(root: Path, name: str, script: str, batch: int) -> dict:
    try:
        py = ensure_venv(root, name)
    except subprocess.CalledProcessError as exc:
        return {"error": f"cannot install {PEERS[name]}: {exc.stderr.strip()[-500:]}"}
    env = dict(os.environ, XLA_FLAGS=ONE_THREAD)
    res = subprocess.run([str(py), "-c", script, str(batch)], capture_output=True, text=True,
                         env=env)
    if res.returncode != 0:
        return {"error": res.stderr.strip()[-1500:]}
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venvs", default=str(Path.home() / ".cache" / "softpinn-bench-peers"),
                    help="folder of the peers' virtual environments (created if missing)")
    ap.add_argument("--batch", type=int, default=10_000)
    ap.add_argument("--only", choices=tuple(PEERS), default=None)
    args = ap.parse_args(argv)
    root = Path(args.venvs)
    root.mkdir(parents=True, exist_ok=True)
    scripts = {"jsrm": JSRM, "soromox": SOROMOX}
    out = {name: run_peer(root, name, scripts[name], args.batch)
           for name in PEERS if args.only in (None, name)}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
