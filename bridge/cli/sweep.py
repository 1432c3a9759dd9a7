"""``softpinn sweep DATA.npz --model KIND --out DIR``: a hyperparameter sweep or seed ensemble
through Ray Tune (the optional extra ``softpinn[ray]``); run in :mod:`bridge.cli._sweep_run`.
The settings fixed for every trial are ``softpinn train``'s flags
(:mod:`bridge.cli.trainflags`); ``--grid`` and ``--random`` vary others."""

from __future__ import annotations


def _split_flags(group) -> None:
    group.add_argument("--train-samples", type=int, default=None, metavar="N",
                       help="train on N randomly chosen pairs (train's --samples; default: all)")
    group.add_argument("--test-trajectories", type=int, nargs="+", default=None, metavar="ID",
                       help="trajectory ids held out for testing (default: the test split the "
                       "data file records, else 20%% drawn at random; the same for every trial)")
    group.add_argument("--test-count", type=int, default=None, metavar="K",
                       help="hold out K trajectories drawn at random")


def add_parser(subparsers):
    p = subparsers.add_parser(
        "sweep",
        help="hyperparameter sweep or seed ensemble through Ray Tune (pip install "
        "'softpinn[ray]')",
        description=(
            "Train one run per trial, a grid (--grid) and/or random draws (--random) over the "
            "training settings, times --seeds seeds, on a local Ray instance or a Ray cluster "
            "(--address), ASHA stopping the worse trials early. Writes OUT/trials/<name>/ (each "
            "a run directory of 'softpinn train'), OUT/results.csv, results.json, results.md, "
            "sweep.png (best test loss against each swept setting) and OUT/best, a link to the "
            "best trial. Needs Ray: pip install 'softpinn[ray]'."
        ),
    )
    p.set_defaults(func=run, given=frozenset())
    return p


def add_arguments(p) -> None:
    # deferred: jax at start-up (train's flags and their defaults are TrainConfig's)
    from softpinn.bridge.cli.trainflags import (
        MODEL_KINDS,
        SWEEP_OWN,
        add_network_flags,
        add_setting_flags,
        track_given,
    )

    # deferred: jax and casadi at start-up (the sweep's choices)
    from softpinn.bridge.sweep import METRICS, SCHEDULERS
    from softpinn.bridge.sweep.space import RANDOM_KINDS  # deferred, as the line above

    p.add_argument("data", metavar="DATA.npz", help="dataset file")
    p.add_argument("--model", choices=MODEL_KINDS, default=None, help="network kind (required)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder of the sweep")
    s = p.add_argument_group("sweep")
    s.add_argument("--grid", action="append", default=None, metavar="SETTING=V1,V2,...",
                   help="try every value of a training setting (repeat the flag for more "
                   "settings: every combination is tried), e.g. lr=1e-3,3e-3 or "
                   "batch-size=64,128; a setting is any train flag without its dashes")
    s.add_argument("--random", action="append", default=None, metavar="SETTING=RANGE",
                   help="draw a setting at random, --samples times: RANGE is "
                   + ", ".join(f"{k}:LOW:HIGH" for k in RANDOM_KINDS if k != "choice")
                   + " or choice:A,B,... (log: log-uniform; int, logint: integers, both ends "
                   "included), e.g. lr=log:1e-4:1e-2")
    s.add_argument("--samples", type=int, default=1, metavar="N",
                   help="random draws (each tried with every --grid combination); not train's "
                   "--samples, which is --train-samples here")
    s.add_argument("--seeds", type=int, default=1, metavar="K",
                   help="train every combination with K seeds (--seed S..S+K-1), one trial "
                   "each: an ensemble spread over the cluster")
    s.add_argument("--random-seed", type=int, default=0, metavar="N",
                   help="seed of the --random draws")
    s.add_argument("--scheduler", choices=SCHEDULERS, default="asha",
                   help="asha: stop trials whose loss is among the worse at rungs of "
                   "GRACE * FACTOR^k epochs; none: run every trial to the end")
    s.add_argument("--metric", choices=METRICS, default="best_test_loss",
                   help="what ASHA compares at its rungs (the trials are ranked by their best "
                   "test loss, that of the model each run keeps)")
    s.add_argument("--grace-period", type=int, default=None, metavar="EPOCHS",
                   help="epochs before ASHA may stop a trial (default: a tenth of --epochs)")
    s.add_argument("--reduction-factor", type=float, default=2.0, metavar="FACTOR",
                   help="ASHA keeps the best 1/FACTOR of the trials at each rung")
    r = p.add_argument_group("Ray")
    r.add_argument("--address", default=None, metavar="HOST:PORT",
                   help="a running Ray cluster: HOST:PORT of its head ('auto' on one of its "
                   "nodes, ray://HOST:10001 through Ray Client); --out must be a folder every "
                   "node sees (default: start a local Ray instance)")
    r.add_argument("--cpus", type=int, default=None, metavar="N",
                   help="CPUs of the local Ray instance (default: all)")
    r.add_argument("--cpus-per-trial", type=float, default=1.0, metavar="N",
                   help="CPUs Ray reserves for each trial")
    r.add_argument("--gpus-per-trial", type=float, default=0.0, metavar="N",
                   help="GPUs Ray reserves for each trial (0.5: two trials share one GPU; 0: "
                   "the trials run on CPU)")
    r.add_argument("--max-concurrent", type=int, default=None, metavar="N",
                   help="at most N trials at once (default: as many as the resources allow)")
    add_setting_flags(p, skip=SWEEP_OWN, split_flags=_split_flags,
                      title=lambda g: f"{g} (fixed for every trial unless swept)")
    add_network_flags(p, "network (fixed for every trial)")
    o = p.add_argument_group("output")
    o.add_argument("--force", action="store_true",
                   help="write into a folder that holds other things (removes nothing of "
                   "yours)")
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    o.add_argument("--verbose", action="store_true",
                   help="Ray Tune's own status tables and the trials' logs")
    o.add_argument("--json", action="store_true", help="print the results as one JSON object")
    track_given(p)


def run(args) -> int:
    from softpinn.bridge.cli import _sweep_run  # deferred: jax at start-up

    return _sweep_run.run(args)
