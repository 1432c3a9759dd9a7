"""``softpinn matrices MODEL --q ...``: M, M^-1, G, D, A, energy (and C, qdd with ``--qd``) of a
model at one state; run in :mod:`bridge.cli._matrices_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "matrices",
        help="M, M^-1, G, D, A, energy (and C, qdd) of a model at one state",
        description="Evaluate the true matrices of a model (a preset name or a spec .toml) at q "
        "(and qd, u). Matrices are printed as nested row lists with --json.",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument(
        "model", metavar="MODEL", help="preset name (see 'softpinn models') or spec file"
    )
    p.add_argument(
        "--q",
        type=float,
        nargs="+",
        required=True,
        metavar="Q",
        help="generalized coordinates (n values)",
    )
    p.add_argument(
        "--qd",
        type=float,
        nargs="+",
        metavar="V",
        help="generalized velocities (n values); adds C and qdd",
    )
    p.add_argument("--u", type=float, nargs="+", metavar="U", help="inputs (m values; default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _matrices_run  # deferred: casadi at start-up

    return _matrices_run.run(args)
