"""``softpinn excitation DATA MODEL``: how much of the arm's inertia a data set shows, per
direction of the true mass matrix (docs/challenges.md, "Data that show the mass"); run in
:mod:`bridge.cli._excitation_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "excitation",
        help="how much of the arm's inertia a data set shows, per direction of M",
        description=(
            "Along each eigenvector of the true mass matrix M(q) (lightest first), the rms "
            "over the data's samples of the inertial force M q̈, the damping force D q̇ and the "
            "rest (A u - G - C q̇), with the true model's q̈ at the data's q, q̇, u. Where the "
            "inertia is a few percent of the damping, the arm moves quasi-statically in that "
            "direction and no training pins its mass there (nor M⁻¹, which the lightest "
            "directions dominate): excite it near its corner frequency vᵀDv / (2π vᵀMv). "
            "Before training, to check a recording or a simulated experiment design."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("data", metavar="DATA.npz", help="dataset file (simulate or import)")
    p.add_argument("model", metavar="MODEL", help="preset name or spec file of the arm")
    p.add_argument("--trajectories", nargs="+", type=int, default=None, metavar="ID",
                   help="use these trajectories (default: all)")
    p.add_argument("--samples", type=int, default=2000,
                   help="samples drawn from the data (seeded)")
    p.add_argument("--json", action="store_true", help="print every number as one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _excitation_run  # deferred: jax/casadi at start-up

    return _excitation_run.run(args)
