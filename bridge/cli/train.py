"""``softpinn train DATA.npz --model KIND --out RUN``: a physics-inspired (or black-box) model
trained on a dataset file; run in :mod:`bridge.cli._train_run`. The flags of the settings come
from the configs (:mod:`bridge.cli.trainflags`), so they are added when the command is parsed."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "train",
        help="train a physics-inspired (or black-box) model on a dataset file",
        description=(
            "Train Lagrangian (eq. 6), Hamiltonian (eq. 7) or black-box networks with the "
            "one-step Runge-Kutta loss (eqs. 8/9) or the acceleration loss (eq. 10), AdamW. "
            "Writes RUN/config.json, model.eqx, checkpoint.eqx, history.csv, metrics.json, "
            "loss.png (one seed-<s>/ folder per member of an ensemble). --model linear fits "
            "the linear baselines instead (RUN/config.json, arx.json, linear2.json, "
            "linear2_rollout.json, "
            "no_motion.json, metrics.json)."
        ),
    )
    p.set_defaults(func=run, given=frozenset())
    return p


def add_arguments(p) -> None:
    # deferred: jax at start-up (the flags' defaults are TrainConfig's and ModelConfig's)
    from softpinn.bridge.cli.trainflags import (
        LINEAR,
        MODEL_KINDS,
        RESUMABLE,
        add_network_flags,
        add_setting_flags,
        track_given,
    )

    p.add_argument("data", metavar="DATA.npz", help="dataset file")
    p.add_argument("--model", choices=(*MODEL_KINDS, LINEAR), default=None,
                   help="network kind (required); 'linear': the least-squares baselines (ARX "
                   "of order 2 and a linear second-order model, closed form, seconds) that "
                   "'softpinn predict' scores beside no motion")
    p.add_argument("--out", required=True, metavar="RUN", help="run directory to write")
    add_setting_flags(p)
    p.add_argument("--accel-weights-from", default=None, metavar="RUN",
                   help="set --accel-weights from RUN's trained model: mean(s) / s_i, s_i the "
                   "rms of its inertial force M̂ q̈ over the training data (a second pass in "
                   "force space that weighs each coordinate by its own force scale)")
    add_network_flags(p)
    hosts = p.add_argument_group("several processes (hosts)")
    hosts.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                       help="address of process 0 when training on several processes (with "
                       "--num-processes and --process-id; then --devices all)")
    hosts.add_argument("--num-processes", type=int, default=None, metavar="P",
                       help="how many processes train together")
    hosts.add_argument("--process-id", type=int, default=None, metavar="I",
                       help="this process's index, 0 .. P-1 (process 0 writes the run)")
    hosts.add_argument("--cluster", action="store_true",
                       help="take the processes from the cluster's environment (SLURM, Open MPI)")

    folder = p.add_argument_group("run directory")
    folder.add_argument(
        "--resume", action="store_true",
        help="continue the run in --out with its stored options; of the options given again, "
        + ", ".join(f"--{n.replace('_', '-')}" for n in RESUMABLE)
        + " may change, any other change is refused",
    )
    folder.add_argument("--force", action="store_true",
                     help="overwrite an existing run directory (removes only softpinn's files)")
    folder.add_argument("--quiet", action="store_true", help="no progress bar")
    folder.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    track_given(p)


def run(args) -> int:
    from softpinn.bridge.cli import _train_run  # deferred: jax at start-up

    return _train_run.run(args)
