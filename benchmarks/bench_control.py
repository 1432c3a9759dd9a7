"""MPC solve time and tracking per ``--sensitivities`` mode, side by side in one run.

For one arm and its prediction models (the true model, and each learned run given), builds the
controller of ``softpinn control`` once per sensitivities mode (exact, frozen, lifted), then
closes the loop with the true model (cvodes) as the plant along the circle and the steps, the
modes taking turns reference by reference and round by round so that a change of the
machine's load touches them alike. Prints one JSON object: per model and mode the build time,
the RK4 sub-steps, and per reference the tip error (RMS, max), failures, how many iterations
were lifted or redone exactly, and the solve times (median, mean, 95th percentile, max, in ms,
over every round), with the machine and its load average before and after.

The references are ``softpinn control``'s defaults: the radius shrunk until the arm can hold
every target with its bounded inputs (issue 46), ``--duration`` seconds each (default: the
whole circle and four steps).

Usage: ``python benchmarks/bench_control.py [--model task5] [--runs RUN ...]
[--offset-free 0.3] [--offset-free-rate 0] [--rounds 2] [--modes exact frozen lifted]
[--duration S] [--stiffness HR]``
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="task5")
    ap.add_argument("--runs", nargs="*", default=[])
    ap.add_argument("--offset-free", type=float, default=0.3)
    ap.add_argument("--offset-free-rate", type=float, default=0.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--modes", nargs="+", default=["exact", "frozen", "lifted"])
    ap.add_argument("--no-true", action="store_true")
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--stiffness", type=float, default=1.5)
    args = ap.parse_args()
    if args.runs:
        import jax

        jax.config.update("jax_enable_x64", True)

    from softpinn.bridge.control import (
        MPC,
        MPCConfig,
        closed_loop,
        default_center,
        default_input_bounds,
        equilibrium,
        from_run,
        from_true,
        metrics,
        plant,
        tip_output,
    )
    from softpinn.bridge.control.compare import _references, machine
    from softpinn.bridge.control.references import default_radius, reachable_radius
    from softpinn.symbolic.model._true_model import TrueModel
    from softpinn.symbolic.spec._spec import load_spec

    spec = load_spec(args.model)
    tm, output = TrueModel(spec), tip_output(spec)
    center = default_center(spec)
    qc, uc = equilibrium(tm, center)
    lo, hi = default_input_bounds(spec)
    models = [] if args.no_true else [from_true(tm, output, "true")]
    scratch = tempfile.TemporaryDirectory(prefix="bench-control-")
    for i, run in enumerate(args.runs):
        models.append(from_run(run, output, export_dir=f"{scratch.name}/{i}", name=f"run{i}"))
    if not models:
        ap.error("nothing to compare: give --runs, or leave out --no-true")
    load_before = list(os.getloadavg())

    controllers = {}
    for pm in models:
        for mode in args.modes:
            cfg = MPCConfig(sensitivities=mode, offset_free=args.offset_free,
                            offset_free_rate=args.offset_free_rate,
                            stiffness=args.stiffness, u_min=tuple(lo), u_max=tuple(hi))
            t0 = time.perf_counter()
            mpc = MPC(pm, cfg, operating_point=(qc, np.zeros(spec.n), uc))
            controllers[pm.name, mode] = (mpc, time.perf_counter() - t0)
    cfg = next(iter(controllers.values()))[0].config
    refs = _references(tm, output, ["circle", "step"], dt=cfg.dt, horizon=cfg.horizon,
                       center=center, period=4.0, hold=1.0, duration=args.duration,
                       radius=reachable_radius(tm, center, default_radius(spec), lo, hi))
    plant_fn = plant(tm, cfg.dt)
    runs = {key: {r: [] for r in refs} for key in controllers}
    for _ in range(args.rounds):
        for rname, ref in refs.items():
            for key, (mpc, _) in controllers.items():
                runs[key][rname].append(closed_loop(mpc, plant_fn, ref["x0"], ref["R"],
                                                    ref["steps"], u0=ref["u0"]))
    out = {"model": spec.name, "runs": args.runs, "offset_free": args.offset_free,
           "offset_free_rate": args.offset_free_rate,
           "rounds": args.rounds, "machine": machine(), "load_before": load_before,
           "load_after": list(os.getloadavg()), "results": {}}
    for (name, mode), (mpc, build) in controllers.items():
        entry = {"build_seconds": build, "substeps": mpc.substeps}
        for rname, results in runs[name, mode].items():
            met = metrics(results[-1])  # the tracking is the same every round
            s = np.concatenate([r["seconds"] for r in results]) * 1e3
            entry[rname] = {
                "error_rms": met["error_rms"], "error_max": met["error_max"],
                "failures": met["failures"], "lifted_iterations": met["lifted_iterations"],
                "exact_iterations": met["exact_iterations"],
                "solve_ms": {"median": float(np.median(s)), "mean": float(np.mean(s)),
                             "p95": float(np.percentile(s, 95)), "max": float(np.max(s))},
            }
        out["results"].setdefault(name, {})[mode] = entry
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
