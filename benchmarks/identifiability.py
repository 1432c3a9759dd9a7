"""How much a data set says about the mass matrix: velocity data (eq. 10 on q̈) against momentum
data (eq. 10 on q̇ = M⁻¹ p), measured with the true model at the data's own training samples
(:mod:`softpinn.bridge.analysis.identifiability` says how). Prints JSON.

    python benchmarks/identifiability.py DATA.npz --model task5 --test-trajectories 8 9 10 11

Used in RESULTS.md ("Hamiltonian networks from velocity data", "Is it the data?", 27 Nov 2026).
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def main(argv=None):
    from softpinn.bridge.analysis.identifiability import mass_identifiability
    from softpinn.learn._data import difference_accelerations, load_dataset
    from softpinn.symbolic.model._true_model import TrueModel
    from softpinn.symbolic.spec._spec import load_spec

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--model", required=True, help="the data's true model (preset or spec file)")
    ap.add_argument("--test-trajectories", type=int, nargs="*", default=[],
                    help="trajectories left out (the training's test set)")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--g-degree", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    data = load_dataset(args.data)
    spec = load_spec(args.model)
    rows = np.flatnonzero(~np.isin(data.traj, args.test_trajectories))
    pick = np.sort(np.random.default_rng(args.seed).choice(
        rows, size=min(args.samples, rows.size), replace=False))
    q, qd, qdd = data.q[pick], data.qd[pick], data.qdd[pick]
    scale = np.sqrt(np.mean(qdd**2, axis=0))
    label_error = np.sqrt(np.mean((difference_accelerations(data)[pick] - qdd) ** 2, axis=0))
    out = {"data": args.data, "model": args.model,
           "rate_hz": float(1.0 / np.median(np.diff(data.t[data.traj == data.traj[0]]))),
           **mass_identifiability(np.asarray(TrueModel(spec).M(q)), q, qd, qdd,
                                  g_degree=args.g_degree, names=spec.coordinate_names),
           "difference_label_error": (label_error / scale).tolist()}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
