"""``softpinn show MODEL``: a PCC arm of a spec drawn at configurations, or along a trajectory;
run in :mod:`bridge.cli._show_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "show",
        help="draw a PCC arm's backbone at configurations, or animate a trajectory",
        description=(
            "Draw the backbone curve (eqs. 13-14, 27) of a planar or spatial PCC arm: at the "
            "configurations --q (a PNG), or along one trajectory of a dataset file --data (a GIF "
            "animation, or a PNG of four instants when --out ends in .png)."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL", help="preset name or spec file of a PCC arm")
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configurations, n numbers each (several: concatenate them)")
    p.add_argument("--data", metavar="DATA.npz", default=None,
                   help="a dataset file of this model: animate one of its trajectories")
    p.add_argument("--trajectory", type=int, default=None, metavar="ID",
                   help="the trajectory of --data to show (default: its first)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="the picture to write: .png, or .gif for an animation of --data")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")


def run(args) -> int:
    from softpinn.bridge.cli import _show_run  # deferred: casadi and matplotlib at start-up

    return _show_run.run(args)
