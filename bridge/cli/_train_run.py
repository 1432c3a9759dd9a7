"""``softpinn train``: flags mapped onto :func:`softpinn.learn.train`; the progress bar is drawn
from the training events (:class:`bridge.cli.bars.TrainBar`); its parser:
:mod:`bridge.cli.train`. ``--model linear`` fits the least-squares baselines instead
(:func:`train_linear`, ``docs/rundir.md``)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from types import SimpleNamespace

from tqdm.auto import tqdm

from softpinn.actuator import Actuator
from softpinn.bridge.analysis.baselines import BASELINES
from softpinn.bridge.base import outputs
from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli.bars import TrainBar
from softpinn.bridge.cli.runnotes import held_out_text
from softpinn.bridge.cli.trainflags import CUSTOM, LINEAR, NETS, check_linear_flags, model_config
from softpinn.errors import UserError
from softpinn.files import write_json
from softpinn.learn import (
    TrainConfig,
    check_run_dir,
    data_force_weights,
    dataset_info,
    fit_baseline,
    load_dataset,
    load_run,
    read_json,
    recording_defaults,
    resolve_actuator,
    resolve_devices,
    split_trajectories,
    train,
    with_actuator,
)
from softpinn.learn.distributed import initialize, is_writer


def run(args) -> int:
    if args.model == LINEAR:
        return train_linear(args)
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
        chosen, why = recording_defaults(data, _pairs(data, train_ids), mc.kind,
                                         getattr(args, "given", ()))
        for name, value in chosen.items():
            setattr(args, name, value)
        if why and not args.json:
            print(f"softpinn: note: {why}", file=sys.stderr)
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
        info = read_json(Path(result.run_dir) / "config.json")
        print(_validation_text(info))
        print(_actuator_text(info))
        if (info.get("prior") or {}).get("note"):
            print(info["prior"]["note"])
        print(f"run directory: {result.run_dir}")
    return 0


def _pairs(data, train_ids) -> int:
    """The training pairs of ``train_ids`` (consecutive samples of one trajectory)."""
    return int(sum(max(0, data.indices(int(i)).size - 1) for i in train_ids))


def _validation_text(info: dict) -> str:
    """Which trajectories picked the model (--validation), or the note that the test ones did."""
    ids = info["split"].get("validation") or []
    if ids:
        return (f"validation: trajector{'y' if len(ids) == 1 else 'ies'} "
                f"{', '.join(map(str, ids))} (they pick the best epoch; the test loss is only "
                "recorded)")
    notes = info.get("notes") or ["the test loss picks the best epoch"]
    return f"validation: none; {'; '.join(notes)}"


def _actuator_text(info: dict) -> str:
    """The actuator the run applies to the inputs (--actuator) and, where it was chosen from
    the data, how."""
    act = info.get("actuator") or {}
    if not act:
        return "actuator: none"
    note = act.get("note")
    if note:
        return note
    text = Actuator.from_dict({k: act[k] for k in ("time_constant", "delay")}).describe()
    return f"actuator: {text.replace('(given)', '(--actuator)')}"


#: the files of a linear baseline run, in the order written (config.json, the run's mark, last)
LINEAR_FILES = ("no_motion.json", "arx.json", "arx_lags.json", "linear2.json",
                "linear2_rollout.json", "metrics.json", "config.json")
#: format of a linear baseline run's config.json
LINEAR_FORMAT = "softpinn-linear-run"


def train_linear(args) -> int:
    """``train --model linear``: no motion, ARX (order 2), ARX with lags of q and u (order
    chosen on a held-out training trajectory) and the linear second-order model fitted by least
    squares on the training trajectories (closed form) and by its rollout error
    (:mod:`softpinn.learn`'s ``fit_linear_rollout``, seconds), each written
    as its ``to_dict`` JSON, with config.json (the split) and metrics.json (the fit
    residuals): every file whole (:func:`softpinn.files.write_json`)."""
    check_linear_flags(args)
    outputs.hold(args.out, "train")  # one writer of --out at a time (softpinn.locks)
    check_run_dir(args.out, force=args.force)
    if args.test_trajectories is not None and args.test_count is not None:
        raise UserError("give --test-trajectories or --test-count, not both")
    data = load_dataset(args.data)
    test = args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
    train_ids, test_ids = (a.tolist() for a in split_trajectories(data, test=test,
                                                                   seed=args.split_seed))
    actuator, told = resolve_actuator(args.actuator, data, train_ids)
    fit_data = with_actuator(data, actuator)
    start = time.perf_counter()
    models = {kind: fit_baseline(kind, fit_data, train_ids, **options)
              for _, kind, options in BASELINES}
    seconds = time.perf_counter() - start
    split = {"train": train_ids, "test": test_ids}
    fits = {kind: {k: v for k, v in model.info.items() if k != "trajectories"}
            for kind, model in models.items() if kind != "no_motion"}
    metrics = {"model": LINEAR, "seconds": seconds, "split": split, **fits}
    config = {"format": LINEAR_FORMAT, "version": 1,
              "model": {"kind": LINEAR, "n": data.n, "m": data.m,
                        "files": {kind: f"{kind}.json" for kind in models},
                        "names": {kind: name for name, kind, _ in BASELINES}},
              "dataset": dataset_info(data), "split": split,
              "test_trajectories": list(test) if isinstance(test, tuple) else test,
              "split_seed": args.split_seed,
              "actuator": {**actuator.to_dict(), "text": actuator.text(),
                           "setting": args.actuator, "note": told}}
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name in LINEAR_FILES:  # --force: the files of a linear run, nothing else
            (out / name).unlink(missing_ok=True)
        for kind, model in models.items():
            write_json(out / f"{kind}.json", model.to_dict())
        write_json(out / "metrics.json", metrics)
        write_json(out / "config.json", config)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write ({exc.strerror or exc})") from None
    if args.json:
        print(json.dumps({"run": str(out), **nulls(metrics)}, allow_nan=False))
        return 0
    arx, lin, oe = fits["arx"], fits["linear2"], fits["linear2_rollout"]
    lags = models["arx_lags"]
    trajs = f"{len(train_ids)} trajector{'y' if len(train_ids) == 1 else 'ies'}"
    how = "by least squares" if lags.info["fit"] == "least squares" else "by its rollouts"
    print(f"fitted ARX (order 2), a lagged ARX (lags of q and u) and a linear second-order "
          f"model on {trajs} in {seconds:.2g} s: ARX one-step rms {arx['one_step_rms']:.4e} "
          f"(spectral radius {arx['spectral_radius']:.4g}), lagged ARX of order {lags.order} "
          f"fitted {how} "
          f"(chosen by {lags.info['horizon']:g} s rollouts on {lags.info['order_chosen_on']}), "
          f"linear2 q̈ rms {lin['accel_rms']:.4e} (largest real eigenvalue "
          f"{lin['max_real_eigenvalue']:.3g}); fitted by its {oe['horizon']:.3g} s rollout "
          f"error: {oe['least_squares_rollout_error']:.4e} -> {oe['rollout_error']:.4e}")
    print(_actuator_text(config))
    print(held_out_text(out, SimpleNamespace(test_trajectories=test,
                                             split_seed=args.split_seed), data))
    print(f"run directory: {out}")
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
