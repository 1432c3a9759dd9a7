"""``softpinn analyze RUN MODEL``: learned against true M, D, G, A of a trained run, with the
transforms P(q) relating them; run in :mod:`bridge.cli._analyze_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "analyze",
        help="learned against true M, D, G, A of a trained run, with transforms P(q)",
        description=(
            "Evaluate the true (CasADi) and learned (Equinox) matrices at the given q (default: "
            "the paper's table q of a preset and q sampled in its data range), fit the "
            "transforms P(q) relating them, and write report.md, CSV/LaTeX tables and plots."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("run", metavar="RUN", help="run directory written by `softpinn train`")
    p.add_argument("model", metavar="MODEL", help="preset name or spec file of the true model")
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configurations, n numbers each (several q: concatenate them)")
    p.add_argument("--points", type=int, default=200,
                   help="q sampled in the data range when --q is not given (default 200)")
    p.add_argument("--transform", nargs="+", default=None, metavar="NAME",
                   help="pointwise, joint, alpha, constant, smooth, direct (default: all but "
                        "direct; direct is added for Hamiltonian models)")
    p.add_argument("--data", metavar="DATA.npz", default=None,
                   help="compare the force terms G, D q̇, A u and the accelerations M⁻¹ times "
                        "each along these data, and say how much of the inertia they show per "
                        "direction of the true M (as `softpinn excitation`; default: the run's "
                        "own data set, its training trajectories)")
    p.add_argument("--samples", type=int, default=2000,
                   help="data samples for the force and acceleration comparisons (default "
                        "2000; 0: none)")
    p.add_argument("--out", required=True,
                   help="output directory (new, empty, or an earlier analyze's)")
    p.add_argument("--force", action="store_true",
                   help="write into an --out that holds files analyze did not write, or over "
                   "a file of an earlier analysis that was edited since (nothing is removed)")
    p.add_argument("--model-mismatch-ok", action="store_true",
                   help="compare with MODEL although the run was trained on another model's data")
    p.add_argument("--member", type=int, default=None, metavar="SEED",
                   help="the ensemble member to analyze (default: the one with the best test "
                   "loss)")
    p.add_argument("--json", action="store_true", help="print every number as one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _analyze_run  # deferred: jax/casadi at start-up

    return _analyze_run.run(args)
