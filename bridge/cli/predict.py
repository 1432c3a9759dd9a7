"""``softpinn predict RUN DATA.npz``: one-step and rollout errors of a trained model at one or
more horizons, beside the baselines (no motion, the linear models) and the one
verdict line; run in :mod:`bridge.cli._predict_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "predict",
        help="one-step and rollout errors of a trained model",
        description=(
            "One-step test error (eq. 8/9 per pair, mean ± std) and rollouts from the true "
            "initial state with the true inputs over --horizon seconds (mean squared error of q "
            "per trajectory, mean ± std over trajectories), at each --horizon given (one load, "
            "one rollout: the shorter horizons are the longest rollout's first seconds). "
            "Beside them: no motion and the linear models (ARX of order 2, ARX with lags of q "
            "and u of an order chosen on held-out data, linear second order by least squares "
            "and by its rollout error) fitted on the run's "
            "training trajectories and scored on the "
            "same trajectories, and one verdict line. A run of 'train --model linear' is "
            "scored the same way, and the best of its models named."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("run", metavar="RUN", help="run directory written by 'softpinn train'")
    p.add_argument("data", metavar="DATA.npz", help="dataset file")
    p.add_argument("--horizon", type=float, nargs="+", required=True, metavar="S",
                   help="rollout length(s) [s] from each test trajectory's start; several "
                   "give one line each (--plot draws the longest)")
    p.add_argument(
        "--reset-every",
        type=float,
        default=None,
        metavar="S",
        help="re-set the state to the truth every S seconds",
    )
    p.add_argument(
        "--dt",
        type=float,
        default=None,
        metavar="S",
        help="integrate with this step instead of the data's",
    )
    p.add_argument(
        "--trajectories",
        nargs="+",
        default=["auto"],
        metavar="ID",
        help="'test' (the run's held-out ones), 'all', or ids (default: test if "
        "DATA is the training file, else all)",
    )
    p.add_argument("--member", type=int, default=None, help="ensemble member (seed)")
    p.add_argument("--no-baselines", action="store_true",
                   help="leave out the baselines and the verdict line")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (with several horizons: one per horizon, under "
                   "'results')")
    p.add_argument("--plot", default=None, metavar="FILE",
                   help="PNG of predicted vs true q (an existing file is replaced only if "
                   "softpinn wrote it, or with --force)")
    p.add_argument("--force", action="store_true",
                   help="let --plot replace a file that softpinn did not write")


def run(args) -> int:
    from softpinn.bridge.cli import _predict_run  # deferred: jax at start-up

    return _predict_run.run(args)
