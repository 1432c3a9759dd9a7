"""``softpinn import REC.csv [...] --model MODEL --out DATA.npz``: recorded trajectories
(configurations, or tip orientation from an IMU) into a dataset file (docs/import.md); run in
:mod:`bridge.cli._import_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "import",
        help="turn recorded trajectories (CSV) into a dataset file (.npz)",
        description="Read recordings of an arm (CSV with a header row: t, u0.., and q0.. or the "
        "tip orientation), smooth them, take velocities and accelerations, optionally resample, "
        "and write a dataset file that 'softpinn train' reads. The format is in docs/import.md.",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("files", nargs="+", metavar="REC.csv",
                   help="recordings: one trajectory per file, or several told apart by an "
                   "integer 'traj' column")
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="preset name or spec file of the arm: its n coordinates and m inputs, and "
                   "its mass matrix for the momentum p = M(q) qd")
    p.add_argument("--out", required=True, metavar="DATA.npz", help="dataset file to write")
    p.add_argument("--orientation", choices=("quaternion", "rpy"),
                   help="the state is the tip orientation: columns qw,qx,qy,qz or roll,pitch,yaw "
                   "[rad], mapped to the bending of a one-segment spatial PCC arm (the stretch "
                   "is set to 0); default: configuration columns q0..")
    p.add_argument("--smooth", default="none", metavar="METHOD",
                   help="none | movmean:W (MATLAB's movmean, W samples) | savgol:W:P "
                   "(Savitzky-Golay) | polyfit:DEG:W (polynomials over runs of W samples)")
    p.add_argument("--differences", type=int, choices=(2, 4), default=2, metavar="ORDER",
                   help="order of the central differences that give velocities and "
                   "accelerations where the smoother has no derivative of its own (none, "
                   "movmean): 2 (3 samples) or 4 (5 samples: less bias at low rates, 1.34x the "
                   "noise; docs/import.md) (default: %(default)s)")
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="resample every trajectory to this uniform rate after smoothing "
                   "(default: keep the recorded times)")
    p.add_argument("--test-trajectories", type=int, default=0, metavar="K",
                   help="the last K trajectories form the test split recorded in meta (the "
                   "paper: the last 8 of 128)")
    p.add_argument("--observed-only", action="store_true",
                   help="leave out the coordinates the recordings cannot determine (with "
                   "--orientation: the stretch, otherwise set to 0), so networks learn only "
                   "what was measured")
    p.add_argument("--force", action="store_true", help="overwrite an existing DATA.npz")
    p.add_argument("--json", action="store_true",
                   help="print the import's record (meta['import']) as one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _import_run  # deferred: casadi at start-up

    return _import_run.run(args)
