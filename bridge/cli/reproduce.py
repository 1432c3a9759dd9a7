"""``softpinn reproduce TASK --out DIR``: a paper task (or the experiment, the challenges, an arm
of one's own) end to end; run in :mod:`bridge.cli._reproduce_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "reproduce",
        help="a paper task end to end: simulate, train, predict, analyze, report",
        description=(
            "Run one of the paper's five tasks, or the same study of an arm of your own (its "
            "spec file): simulate its data, train the physics model(s) and the black-box "
            "baseline, predict, analyze the learned matrices and write report.md; or the "
            "paper's experiment (Section V, Table IV) on a simulated stand-in: an "
            "IMU records a tendon-driven arm, the recordings are imported with each "
            "preprocessing and at each sensor rate (docs/experiment.md); or the paper's open "
            "challenges (Section VI-B: fast Lagrangian training, a known actuator model and "
            "additional labels, Hamiltonian networks from velocity data; docs/challenges.md); "
            "or a Cosserat-rod arm that is not PCC (PyElastica, the optional extra "
            "'cosserat'): its recordings imported as a real arm's, networks against no motion "
            "and linear models (docs/cosserat.md). "
            "Finished stages are skipped when run again with the same settings."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("task", metavar="TASK",
                   help="task1 ... task5, experiment, challenges, cosserat, or a spec file of "
                        "your own arm (ARM.toml: its [data] and [training] recipe, or "
                        "defaults)")
    p.add_argument("--quick", action="store_true", help="small settings (a minute or two)")
    p.add_argument("--out", required=True,
                   help="output directory (new, empty, or an earlier reproduce's: finished "
                        "stages are reused)")
    p.add_argument("--force", action="store_true",
                   help="write into an --out that holds files reproduce did not write, or over "
                   "a file of an earlier run that was edited since (nothing is removed)")
    p.add_argument("--seeds", type=int, default=1, help="train K seeds, report mean ± std")
    p.add_argument("--epochs", type=int, default=None, help="override every model's epochs")
    p.add_argument("--lbfgs-steps", type=int, default=None,
                   help="override every model's L-BFGS iterations after AdamW")
    p.add_argument("--float32", action="store_true", help="train in float32")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="train and analyse N models at a time, each in a process of its own, "
                        "and draw a task's figures of each data set as soon as its models are "
                        "done (the tasks and the experiment; same results, sooner on a machine "
                        "with cores to spare)")
    p.add_argument("--actuator", default=None, metavar="TAU:DELAY",
                   help="experiment only: the stand-in's tendons follow their commands through a "
                        "first-order lag TAU and a dead time DELAY [s] (one value for all inputs "
                        "or a comma list with one per input, e.g. 0.1:0.06); the commands are "
                        "recorded as u and the networks and baselines are given the actuator "
                        "(docs/experiment.md)")
    p.add_argument("--prior", default=None, choices=("none", "linear", "auto"),
                   help="experiment and cosserat only: the networks start as the least-squares "
                        "linear model of the training data and learn the correction "
                        "(train --prior; default: none for the experiment, the paper's "
                        "networks; auto for cosserat, linear on its imported recordings)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run(args) -> int:
    from softpinn.bridge.cli import _reproduce_run  # deferred: jax/casadi at start-up

    return _reproduce_run.run(args)
