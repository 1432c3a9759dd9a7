"""``softpinn sweep``: flags mapped onto :func:`softpinn.bridge.sweep.sweep` (Ray Tune); a
progress bar counts the finished trials (its parser: :mod:`bridge.cli.sweep`)."""

from __future__ import annotations

import importlib.util
import json
import sys

from tqdm.auto import tqdm

from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli._train_run import nulls
from softpinn.bridge.cli.trainflags import SWEEP_OWN, model_config
from softpinn.bridge.sweep import RAY_MISSING, SweepConfig, parse_space, sweep
from softpinn.bridge.sweep.space import dashed
from softpinn.errors import UserError
from softpinn.learn import TrainConfig, load_dataset


class TrialBar:
    """A tqdm bar (stderr) of finished trials, with the best loss so far; drawn once Ray is up
    (an error before that stays one line)."""

    def __init__(self, disable: bool):
        self.disable = disable
        self.bar = None
        self.best = None

    def __call__(self, info: dict) -> None:
        if self.bar is None:
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


def run(args) -> int:
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

    enable_x64()
    data = load_dataset(args.data)
    test = args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
    fixed = {f.name: getattr(args, f.name) for f in TrainConfig.settings()
             if f.name not in SWEEP_OWN}
    base = TrainConfig(model=model_config(args, data.n, data.m, data), test_trajectories=test,
                       samples=args.train_samples, **fixed)
    config = SweepConfig(samples=args.samples, seeds=args.seeds, random_seed=args.random_seed,
                         address=args.address, num_cpus=args.cpus, scheduler=args.scheduler,
                         metric=args.metric, grace_period=args.grace_period,
                         reduction_factor=args.reduction_factor,
                         cpus_per_trial=args.cpus_per_trial,
                         gpus_per_trial=args.gpus_per_trial,
                         max_concurrent=args.max_concurrent)
    bar = TrialBar(disable=args.quiet or args.verbose)
    try:
        result = sweep(data, base, space, args.out, config, force=args.force,
                       verbose=2 if args.verbose else 0, progress=bar)
    finally:
        bar.close()
    rows, best = result.rows, result.best
    if args.json:
        print(json.dumps(nulls({"out": str(result.out), "best": best, "trials": len(rows),
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
