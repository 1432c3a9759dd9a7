"""``softpinn sweep``: flags mapped onto :func:`softpinn.bridge.sweep.sweep` (Ray Tune; the
optional extra ``softpinn[ray]``). The settings fixed for every trial are ``softpinn train``'s
flags; ``--grid`` and ``--random`` vary others; a progress bar counts the finished trials."""

from __future__ import annotations

import json
import sys

from softpinn.bridge.sweep import METRICS, RAY_MISSING, SCHEDULERS, parse_space, sweep
from softpinn.bridge.sweep.space import RANDOM_KINDS, dashed
from softpinn.errors import UserError
from softpinn.learn import TrainConfig, load_dataset

#: train flags the sweep spells otherwise or leaves out: its --seeds and --samples are its own,
#: and a trial trains one seed, so the ensemble mode does not apply
_OWN = ("seeds", "samples", "test_trajectories", "ensemble")


def _split_flags(group) -> None:
    group.add_argument("--train-samples", type=int, default=None, metavar="N",
                       help="train on N randomly chosen pairs (train's --samples; default: all)")
    group.add_argument("--test-trajectories", type=int, nargs="+", default=None, metavar="ID",
                       help="trajectory ids held out for testing (default: the test split the "
                       "data file records, else 20%% drawn at random; the same for every trial)")
    group.add_argument("--test-count", type=int, default=None, metavar="K",
                       help="hold out K trajectories drawn at random")


def _add_settings(parser) -> None:
    """``softpinn train``'s setting and network flags (defaults and help from the configs),
    less the ones a sweep decides per trial (seeds) or names otherwise (--train-samples)."""
    from softpinn.bridge.cli.learn import add_network_flags, add_setting_flags

    add_setting_flags(parser, skip=_OWN, split_flags=_split_flags,
                      title=lambda g: f"{g} (fixed for every trial unless swept)")
    add_network_flags(parser, "network (fixed for every trial)")


def register(subparsers) -> None:

    from softpinn.bridge.cli.learn import MODEL_KINDS, track_given

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
    _add_settings(p)
    o = p.add_argument_group("output")
    o.add_argument("--force", action="store_true",
                   help="write into a folder that holds other things (removes nothing of "
                   "yours)")
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    o.add_argument("--verbose", action="store_true",
                   help="Ray Tune's own status tables and the trials' logs")
    o.add_argument("--json", action="store_true", help="print the results as one JSON object")
    p.set_defaults(func=cmd_sweep, given=frozenset())
    track_given(p)


class _Bar:
    """A tqdm bar (stderr) of finished trials, with the best loss so far; drawn once Ray is up
    (an error before that stays one line)."""

    def __init__(self, disable: bool):
        self.disable = disable
        self.bar = None
        self.best = None

    def __call__(self, info: dict) -> None:
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=info["total"], file=sys.stderr, unit="trial", desc="sweep",
                            dynamic_ncols=True, disable=self.disable)
        loss = info.get("best_test_loss")
        if loss is not None and loss == loss and (self.best is None or loss < self.best):
            self.best = loss
        if info["event"] in ("complete", "error"):
            self.bar.update(max(0, info["finished"] - self.bar.n))
        if self.best is not None:
            self.bar.set_postfix({"best": f"{self.best:.3e}"}, refresh=False)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def cmd_sweep(args) -> int:
    import importlib.util


    try:
        have_ray = importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        have_ray = False
    if not have_ray:
        raise UserError(RAY_MISSING)

    space = parse_space(args.grid or [], args.random or [])
    for name in space:
        if name in args.given:
            raise UserError(f"--{dashed(name)} is fixed for every trial and swept with "
                            f"--grid/--random: give one")
    if args.test_trajectories is not None and args.test_count is not None:
        raise UserError("give --test-trajectories or --test-count, not both")

    import jax

    jax.config.update("jax_enable_x64", True)

    from softpinn.bridge.cli.learn import _model_config

    data = load_dataset(args.data)
    test = args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
    fixed = {f.name: getattr(args, f.name) for f in TrainConfig.settings() if f.name not in _OWN}
    base = TrainConfig(model=_model_config(args, data.n, data.m, data), test_trajectories=test,
                       samples=args.train_samples, **fixed)
    bar = _Bar(disable=args.quiet or args.verbose)
    try:
        result = sweep(data, base, space, args.out, samples=args.samples, seeds=args.seeds,
                       address=args.address, scheduler=args.scheduler, metric=args.metric,
                       cpus_per_trial=args.cpus_per_trial, gpus_per_trial=args.gpus_per_trial,
                       max_concurrent=args.max_concurrent, num_cpus=args.cpus,
                       grace_period=args.grace_period, reduction_factor=args.reduction_factor,
                       random_seed=args.random_seed, force=args.force,
                       verbose=2 if args.verbose else 0, progress=bar)
    finally:
        bar.close()
    rows, best = result.rows, result.best
    if args.json:
        from softpinn.bridge.cli.learn import _nulls

        print(json.dumps(_nulls({"out": str(result.out), "best": best, "trials": len(rows),
                                 "results": rows}), allow_nan=False))
        return 0 if best is not None else 1
    counts = {"completed": sum(r["status"] == "completed" for r in rows),
              "stopped early": sum(r["stopped_early"] for r in rows),
              "diverged": sum(r["status"] == "diverged" for r in rows),
              "failed": sum(r["path"] is None for r in rows)}
    print(f"{len(rows)} trials: " + ", ".join(f"{n} {k}" for k, n in counts.items()
                                              if n or k in ("completed", "stopped early")))
    if best is None:
        errors = [r["status"] for r in rows if r["status"].startswith("error")]
        print("no trial reached a finite test loss" + (f" ({errors[0]})" if errors else "")
              + "; see " + str(result.out / "results.md"))
        return 1
    settings = ", ".join(f"{dashed(k)}={v}" for k, v in best["settings"].items())
    print(f"best: {best['trial']} ({settings}{', ' if settings else ''}seed {best['seed']}), "
          f"best test loss {best['best_test_loss']:.4e}")
    print(f"best run: {result.out / 'best'} -> {result.best_dir}")
    print(f"results: {result.out / 'results.md'}")
    return 0
