"""``softpinn train``: flags mapped onto :func:`softpinn.learn.train`; the progress bar is drawn
from the training events (:class:`bridge.cli.bars.TrainBar`); its parser:
:mod:`bridge.cli.train`."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

from tqdm.auto import tqdm

from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli.bars import TrainBar
from softpinn.bridge.cli.runnotes import held_out_text
from softpinn.bridge.cli.trainflags import CUSTOM, NETS, model_config
from softpinn.errors import UserError
from softpinn.learn import (
    TrainConfig,
    check_run_dir,
    data_force_weights,
    load_dataset,
    load_run,
    read_json,
    resolve_devices,
    split_trajectories,
    train,
)
from softpinn.learn.distributed import initialize, is_writer


def run(args) -> int:
    enable_x64()

    initialize(args.coordinator, args.num_processes, args.process_id, cluster=args.cluster)
    if not is_writer():
        args.quiet = True  # one progress bar: process 0's

    if args.resume and args.force:
        raise UserError("--resume and --force exclude each other")

    check_run_dir(args.out, force=args.force, resume=args.resume)  # before any work or bar
    if args.test_trajectories is not None and args.test_count is not None:
        raise UserError("give --test-trajectories or --test-count, not both")
    if args.resume:
        if args.accel_weights_from is not None:
            raise UserError("--accel-weights-from: give it when a run starts (the weights are "
                            "stored in the run's config.json), not with --resume")
        stored = read_json(Path(args.out) / "config.json")
        if not isinstance(stored, dict) or "train" not in stored:
            raise UserError(f"--resume: {Path(args.out) / 'config.json'} is not a softpinn run")
        config = TrainConfig.from_dict(stored["train"])
        data = load_dataset(args.data, n=config.model.n, m=config.model.m)
        config = _resumed_with_flags(args, config, data)
    else:
        data = load_dataset(args.data)
        test = args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
        # the training split as train() draws it: --mass-init data reads no test trajectory
        train_ids, _ = split_trajectories(data, test=test, seed=args.split_seed)
        mc = model_config(args, data.n, data.m, data, train_ids)
        if args.accel_weights_from is not None:
            if args.accel_weights is not None:
                raise UserError("give --accel-weights or --accel-weights-from, not both")
            args.accel_weights = _weights_from(args.accel_weights_from, data, train_ids,
                                               args.accel_labels)
        config = TrainConfig(
            model=mc, test_trajectories=test,
            **{f.name: getattr(args, f.name) for f in TrainConfig.settings()
               if f.name not in CUSTOM},
        )

    resolve_devices(config.devices)  # before the bar: a refusal is one line
    bar = TrainBar(config.epochs * config.seeds, disable=args.quiet)
    bar.start()
    try:
        result = train(
            data,
            config,
            args.out,
            progress=bar,
            force=args.force,
            resume=args.resume,
            warn=_warn,
        )
    finally:
        bar.close()
    if not is_writer():
        return 0  # process 0 reports
    m = result.metrics
    if args.json:
        print(json.dumps({"run": str(result.run_dir), **nulls(m)}, allow_nan=False))
    else:
        bt = m["best_test_loss"]
        print(
            f"trained {len(m['seeds'])} seed(s) of a {config.model.kind} model on "
            f"{m['pairs']['train']} pairs ({m['ensemble_mode']})"
        )
        spread = f" ± {bt['std']:.3e}" if len(m["seeds"]) > 1 else ""
        print(f"best test loss: {bt['mean']:.4e}{spread}   (best seed {m['best_member']})")
        print(held_out_text(result.run_dir, config, data))
        print(f"run directory: {result.run_dir}")
    return 0


def _weights_from(run_dir: str, data, train_ids, labels: str) -> list[float]:
    """``--accel-weights-from RUN``: :func:`softpinn.learn.data_force_weights` of RUN's best
    model over the training trajectories' samples, with q̈ labels as ``--accel-labels`` takes
    them."""
    run = load_run(run_dir)
    if run.model_config.kind not in ("lagrangian", "hamiltonian") or (
            run.model_config.n != data.n):
        raise UserError(f"--accel-weights-from {run_dir}: needs a lagrangian or hamiltonian run "
                        f"of the data's n = {data.n} coordinates")
    return list(data_force_weights(run.model, data, train_ids, labels))


def _warn(message: str) -> None:
    """A setting warning of the library, naming the flag instead of the field."""
    field, sep, rest = message.partition(": ")
    if sep and field.isidentifier():
        message = f"--{field.replace('_', '-')}: {rest}"
    message = message.replace("or 'data' to", "or --mass-init data to")
    tqdm.write(f"softpinn: warning: {message}", file=sys.stderr)


#: train flags that are not settings of the run
_RUN_FLAGS = frozenset({"out", "resume", "force", "quiet", "json", "given", "coordinator",
                        "num_processes", "process_id", "cluster", "accel_weights_from"})
_MODEL_FLAGS = frozenset({"model", "width", "depth", "activation", "damping_form", "input_form",
                          "eps", "mass_init", "state", "float32", "known_input", *NETS})


def _resumed_with_flags(args, stored, data):
    """The stored configuration with the settings typed again on the command line (the library
    keeps those that may change on resume and refuses the others, naming them)."""
    given = set(args.given) - _RUN_FLAGS
    if args.model == stored.model.kind:  # the run's own kind typed again: no change
        given.discard("model")
    elif "model" in given:
        raise UserError(f"--resume: the run holds a {stored.model.kind} model; --model "
                        f"{args.model} cannot continue it (train a new run into another --out)")
    fields = {f.name for f in dataclasses.fields(stored)}
    changes = {name: getattr(args, name) for name in given & fields}
    if given & {"test_trajectories", "test_count"}:
        changes["test_trajectories"] = (
            args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
        )
    if given & _MODEL_FLAGS:
        if args.model is None:
            args.model = stored.model.kind
        split = changes.get("test_trajectories", stored.test_trajectories)
        train_ids, _ = split_trajectories(data, test=split, seed=stored.split_seed)
        changes["model"] = model_config(args, data.n, data.m, data, train_ids)
    return dataclasses.replace(stored, **changes) if changes else stored


def nulls(obj):
    """``obj`` with every NaN and inf as None (JSON's null), in dicts and lists."""
    if isinstance(obj, dict):
        return {k: nulls(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [nulls(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
