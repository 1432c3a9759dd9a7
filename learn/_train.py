"""Training of the dynamics models: AdamW with a learning-rate schedule, minibatches of fixed
shape, jitted epochs, early stopping, seeded ensembles, checkpoints, resume, L-BFGS finish.

The losses are the one-step Runge-Kutta losses of eqs. 8 (velocity state) and 9 (momentum
state), or the acceleration loss of eq. 10, from :mod:`learn._losses`; the optimizer is AdamW
(Section III-B, "Model training"), via optax.

The pieces live by job: the settings in :mod:`learn._config`, the jitted programs and their
cache in :mod:`learn._programs`, the ensemble engine (checkpoints, NaN rollback, interrupts) in
:mod:`learn._ensemble`, the run directory and :func:`load_run` in :mod:`learn._rundir`. This
module only orchestrates: data and split, the run directory, the members, the aggregate.
The "sequential" ensemble mode runs the K = 1 engine once per seed with the same compiled
functions, so an ensemble member gives the same parameters as a single run with its seed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from softpinn import locks
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn import distributed
from softpinn.learn._actuator import (
    RESOLVED_FROM_DATA,
    resolve_actuator,
    run_actuator,
    with_actuator,
)
from softpinn.learn._advice import setting_warnings, warn_setting
from softpinn.learn._config import (
    ENSEMBLE_MODES,
    FORMAT,
    FORMAT_VERSION,
    LOSSES,
    RESUMABLE,
    SCHEDULES,
    TrainConfig,
)
from softpinn.learn._data import (
    Dataset,
    load_dataset,
    make_pairs,
    make_windows,
)
from softpinn.learn._devices import resolve_devices
from softpinn.learn._ensemble import (
    MemberGroup,
    MemberResult,
    NonFiniteStart,
    TrainingDiverged,
    finish_member,
)
from softpinn.learn._losses import equilibria_of
from softpinn.learn._members import resolve_ensemble_mode
from softpinn.learn._models import ensure_dtype
from softpinn.learn._objective import (
    check_rollout_schedule,
    resolve_test_steps,
    to_pairs,
    to_windows,
)
from softpinn.learn._prior import resolve_prior
from softpinn.learn._programs import PROGRAMS, ProgramCache, _chunked
from softpinn.learn._rundir import (
    LoadedRun,
    aggregate_metrics,
    dataset_info,
    load_ensemble,
    load_run,
    loss_plot,
    mean_history,
    member_dir,
)
from softpinn.learn._splits import split_trajectories, validation_split
from softpinn.learn._velocity import resolve_momenta
from softpinn.progress import ProgressFn

__all__ = [
    "ENSEMBLE_MODES",
    "FORMAT",
    "FORMAT_VERSION",
    "LOSSES",
    "SCHEDULES",
    "LoadedRun",
    "MemberResult",
    "ProgramCache",
    "TrainConfig",
    "TrainResult",
    "TrainingDiverged",
    "load_ensemble",
    "load_run",
    "train",
]

@dataclass
class TrainResult:
    """What :func:`train` returns: the members and the aggregate metrics (mean ± std)."""

    run_dir: Path
    config: TrainConfig
    members: list[MemberResult]
    metrics: dict

    @property
    def model(self):
        """The best member's model (lowest best validation loss where the run held out
        validation trajectories, else lowest best test loss)."""
        return min(self.members, key=lambda r: r.metrics.get(
            "best_validation_loss", r.metrics["best_test_loss"])).model


def _held_out(data, ids, config, state, dtype):
    """The held-out pairs (windows of loss "rollout" or of ``test_with`` "rollout") of
    trajectories ``ids``, as numpy and as the arrays the programs take (at most
    ``config.test_samples`` of them)."""
    if config.loss == "rollout" or config.test_with == "rollout":
        h, samples = config.rollout_steps, config.test_samples
        if config.test_with == "rollout":  # long windows: about ten per horizon by default
            h = config.test_steps
            longest = max(int(data.indices(int(k)).size) for k in np.asarray(ids).tolist())
            if h >= longest:
                raise UserError(f"test_steps: {h} steps is longer than every held-out "
                                f"trajectory (at most {longest - 1} steps); give fewer")
            if samples is None:
                samples = sum(-(-10 * int(data.indices(int(k)).size) // h)
                              for k in np.asarray(ids).tolist())
        held = make_windows(data, ids, horizon=h, state=state, samples=samples,
                            seed=config.split_seed)
        return held, to_windows(held, dtype)
    held = make_pairs(data, ids, state=state, samples=config.test_samples,
                      seed=config.split_seed, accel=config.accel_labels)
    if config.loss != "accel":
        held = held._replace(xdot0=None)
    return held, to_pairs(held, dtype)


def _test_evaluator(prog, pairs, count):
    """The test loss of ``count`` held-out ``pairs`` with the run's compiled evaluation (the
    chunks have the programs' one shape: nothing compiles again), for a run whose validation
    loss picks the model."""
    chunks = _chunked(pairs, prog.eval_size)
    return lambda params: prog._evaluate(prog._eval_test_chunk, params, chunks, count)


def _remove_run(run_dir: Path, seeds) -> None:
    """Remove what a fresh run wrote (its manifests' files), e.g. when it could not start."""
    for s in seeds if len(seeds) > 1 else []:
        if member_dir(run_dir, s, len(seeds)).is_dir():
            ckpt.remove_written(member_dir(run_dir, s, len(seeds)))
    ckpt.remove_written(run_dir)


def _member_groups(prog, seeds, mode, run_dir, test_eval=None) -> list[MemberGroup]:
    """One group of all members (vmap) or one group per member (sequential); ``test_eval``:
    the test loss of a run whose validation loss picks (:class:`learn._ensemble.MemberGroup`)."""
    K = len(seeds)
    head = {"format": FORMAT}
    if mode == "vmap":
        return [MemberGroup(prog, seeds, run_dir / "checkpoint.eqx", head, test_eval)]
    return [MemberGroup(prog, [s], member_dir(run_dir, s, K) / "checkpoint.eqx", head, test_eval)
            for s in seeds]


# ---------------------------------------------------------------------------------- resume


def resumed_config(stored: TrainConfig, given: TrainConfig, run_dir: Path) -> TrainConfig:
    """The configuration a resumed run continues with: the stored one, with the settings of
    :data:`learn._config.RESUMABLE` (epochs, patience, L-BFGS steps, ...) taken from ``given``.
    Any other difference would make it another run: refused, naming every differing field."""
    def differ(a, b, prefix=""):
        return [
            f"{prefix}{f.name} (run: {getattr(a, f.name)!r}, given: {getattr(b, f.name)!r})"
            for f in dataclasses.fields(a)
            if getattr(a, f.name) != getattr(b, f.name) and f.name != "model"
        ]

    other = [d for d in differ(stored, given) if d.split(" ")[0] not in RESUMABLE]
    other += differ(stored.model, given.model, "model.")
    if other:
        raise UserError(
            f"resume: {run_dir} was trained with other settings, which cannot change on resume: "
            f"{'; '.join(other)} (only {', '.join(RESUMABLE)} may)"
        )
    return dataclasses.replace(stored, **{k: getattr(given, k) for k in RESUMABLE})


def update_stored_config(run_dir: Path, stored: dict, config: TrainConfig) -> None:
    """Record the resumed settings in the run's (and its members') config.json."""
    ckpt.atomic_write_json(run_dir / "config.json", {**stored, "train": config.to_dict()},
                           record=True)
    for name in stored.get("members", []):
        path = run_dir / name / "config.json"
        if path.is_file():
            info = ckpt.read_json(path)
            ckpt.atomic_write_json(path, {**info, "train": config.to_dict()}, record=True)


# ---------------------------------------------------------------------------------- train


@locks.scope()  # the run directory's claim (ckpt.prepare_run_dir) ends with the run
def train(
    data: Dataset | str | Path,
    config: TrainConfig | None,
    out_dir: str | Path,
    *,
    progress: ProgressFn | None = None,
    force: bool = False,
    resume: bool = False,
    programs: ProgramCache | None = None,
    warn: Callable[[str], None] | None = None,
    _shadow: bool = False,
) -> TrainResult:
    """Train ``config.seeds`` models on ``data`` and write the run directory ``out_dir``.

    ``out_dir`` gets ``config.json``, ``model.eqx`` (the best parameters), ``checkpoint.eqx``
    (everything needed to resume), ``history.csv``, ``metrics.json`` and ``loss.png``; an
    ensemble gets one such folder ``seed-<s>/`` per member and aggregate files on top.
    ``resume=True`` continues the run in ``out_dir`` from its last checkpoint with its stored
    configuration (``config`` may be None; if given, it may differ from the stored one only in
    :data:`learn._config.RESUMABLE`, e.g. more ``epochs``, which are honoured). An existing,
    non-empty ``out_dir`` is refused unless ``force`` or ``resume``. ``progress(event)`` is
    called after every epoch with a :class:`softpinn.progress.TrainProgress` (the CLI draws a
    progress bar from it).
    Raises :class:`TrainingDiverged` on a NaN/inf loss (the last good checkpoint is kept);
    on KeyboardInterrupt it saves a checkpoint and re-raises. ``programs``: the cache of
    compiled programs to use (default: the process's, :data:`learn._programs.PROGRAMS`).
    ``warn(message)`` gets one line per setting that is clearly off for the data (see
    :mod:`learn._advice`; default: a warning of the ``softpinn.learn`` logger).
    """
    programs = PROGRAMS if programs is None else programs
    # several processes: process 0 writes the run directory, the others a private copy
    if not _shadow and not distributed.is_writer():
        shadow = distributed.shadow_dir(out_dir, resume=resume)
        try:
            return train(data, config, shadow, progress=progress, resume=resume,
                         programs=programs, warn=lambda message: None, _shadow=True)
        finally:
            distributed.drop_shadow(shadow)
    run_dir = ckpt.prepare_run_dir(out_dir, force=force, resume=resume)
    if resume:
        stored = ckpt.read_json(run_dir / "config.json")
        if stored.get("format") != FORMAT:
            raise UserError(f"{run_dir}/config.json: not a softpinn run directory")
        stored_cfg = TrainConfig.from_dict(stored["train"])
        if stored_cfg.seeds > 1 and "members" not in stored:
            # a member folder: resuming it alone would start a new K-member ensemble inside it
            raise UserError(
                f"--resume: {run_dir} holds one member (seed {stored.get('seed')}) of a "
                f"{stored_cfg.seeds}-member ensemble; resume the ensemble's directory "
                f"({run_dir.parent} if this folder was not moved): its members resume together"
            )
        if (config is not None and config.momenta == "auto"
                and stored_cfg.momenta != config.momenta):
            config = dataclasses.replace(config, momenta=stored_cfg.momenta)  # auto: as decided
        if config is not None and config.actuator in RESOLVED_FROM_DATA:
            config = dataclasses.replace(config, actuator=stored_cfg.actuator)  # as resolved
        if config is not None and config.model.prior is None and config.prior != "none":
            # the prior's numbers, as fitted when the run started (auto: as decided)
            config = dataclasses.replace(
                config, prior=stored_cfg.prior,
                model=dataclasses.replace(config.model, prior=stored_cfg.model.prior))
        changed = config is not None and config != stored_cfg
        config = resumed_config(stored_cfg, config, run_dir) if changed else stored_cfg
        changed = config != stored_cfg
    elif config is None:
        raise UserError("train: a TrainConfig is needed unless resuming")
    if not isinstance(data, Dataset):
        data = load_dataset(data, n=config.model.n, m=config.model.m)
    if data.n != config.model.n or data.m != config.model.m:
        raise UserError(
            f"dataset file {data.path}: model has n={config.model.n}, m={config.model.m}; "
            f"the file has n={data.n}, m={data.m}"
        )
    if resume and stored["dataset"]["sha256"] != data.sha256:
        raise UserError(
            f"--resume: {data.path} is not the dataset the run in {run_dir} was trained on "
            f"(sha256 differs from {stored['dataset']['path']})"
        )
    if not resume:  # a Hamiltonian network's momenta: from the data or its velocities
        config = resolve_momenta(config, data)
    ensure_dtype(config.model.dtype)
    dtype = jnp.dtype(config.model.dtype)

    note = None
    if resume and isinstance(stored.get("split"), dict):
        # the split the run was trained with, as it recorded it: a default that changed since
        # (a recorded test split of the file instead of 20% at random, validation trajectories
        # held out since issue 43: a run without "validation" has none) must not move it
        train_ids = np.asarray(stored["split"]["train"], dtype=np.int64)
        test_ids = np.asarray(stored["split"]["test"], dtype=np.int64)
        val_ids = np.asarray(stored["split"].get("validation", []), dtype=np.int64)
    else:
        train_ids, test_ids = split_trajectories(
            data, test=config.test_trajectories, seed=config.split_seed
        )
        train_ids, val_ids, note = validation_split(data, train_ids, config.validation,
                                                    seed=config.split_seed)
    if resume:
        actuator_info = stored.get("actuator")
    else:  # the actuator's numbers, once: the run stores them (learn/_actuator.py)
        asked = config.actuator
        actuator, told = resolve_actuator(asked, data, train_ids)
        config = dataclasses.replace(config, actuator=actuator.text())
        actuator_info = {**actuator.to_dict(), "setting": asked, "note": told}
    data = with_actuator(data, run_actuator(config.actuator, data.m))
    prior_info = stored.get("prior") if resume else None
    if not resume and config.model.prior is None:  # the linear prior, fitted once (_prior.py)
        asked = config.prior
        text, told = resolve_prior(asked, data, train_ids, val_ids,
                                   input_hold=config.input_hold)
        if text is not None:
            config = dataclasses.replace(config, prior="linear",
                                         model=dataclasses.replace(config.model, prior=text))
            prior_info = {"setting": asked, "note": told}
    config = resolve_test_steps(config, data, np.concatenate([val_ids, test_ids]))
    state = config.model.state_kind
    if config.loss == "rollout":
        check_rollout_schedule(config, data, train_ids)
        h = config.rollout_steps
        train_np = make_windows(
            data, train_ids, horizon=h, state=state, samples=config.samples, seed=config.split_seed
        )
        train_pairs = to_windows(train_np, dtype)
    else:
        train_np = make_pairs(
            data, train_ids, state=state, samples=config.samples, seed=config.split_seed,
            accel=config.accel_labels,
        )
        if config.loss != "accel":
            train_np = train_np._replace(xdot0=None)
        train_pairs = to_pairs(train_np, dtype)
    test_np, test_pairs = _held_out(data, test_ids, config, state, dtype)
    # the pairs whose loss picks the model: the validation trajectories', where there are any
    val_np, val_pairs = (_held_out(data, val_ids, config, state, dtype) if val_ids.size
                         else (test_np, test_pairs))
    devices = resolve_devices(config.devices)
    batch = config.batch_for(train_np.count, devices)
    if not resume:
        for message in setting_warnings(config, data, train_np.count, batch):
            (warn or warn_setting)(message)

    labels = None
    if config.equilibrium_weight > 0 or config.force_weight > 0:
        labels = equilibria_of(data, dtype)  # refused with one line when the file has none
    prog = programs.get(config, train_pairs, val_pairs, train_np.count, batch, devices,
                        labels=labels)
    test_eval = _test_evaluator(prog, test_pairs, test_np.count) if val_ids.size else None

    seeds = [config.seed + i for i in range(config.seeds)]
    mode = resolve_ensemble_mode(config.ensemble, config.seeds)
    K = len(seeds)
    base = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "train": config.to_dict(),
        "model": config.model.to_dict(),
        "dataset": dataset_info(data),
        "split": {"train": train_ids.tolist(), "validation": val_ids.tolist(),
                  "test": test_ids.tolist()},
        "pairs": {"train": train_np.count, "test": test_np.count, "batch": batch,
                  **({"validation": val_np.count} if val_ids.size else {})},
        **({"notes": [note]} if note else {}),
        **({"actuator": actuator_info} if actuator_info else {}),
        **({"prior": prior_info} if prior_info else {}),
        "devices": devices,
        "steps_per_epoch": prog.steps,
        "ensemble_mode": mode,
    }
    try:
        if not resume:
            top = dict(base)
            if K > 1:
                top["members"] = [f"{ckpt.MEMBER_PREFIX}{s}" for s in seeds]
                top["seeds"] = seeds
            else:
                top["seed"] = seeds[0]
            ckpt.atomic_write_json(run_dir / "config.json", top, record=True)
            for s in seeds if K > 1 else []:
                mdir = member_dir(run_dir, s, K)
                ckpt.atomic_write_json(mdir / "config.json", {**base, "seed": s}, record=True)
        groups = _member_groups(prog, seeds, mode, run_dir, test_eval)
    except BaseException:
        if not resume:  # nothing trained yet: leave nothing that blocks a rerun
            _remove_run(run_dir, seeds)
        raise
    if resume:
        for g in groups:
            if g.ckpt_path.is_file():
                g.restore()  # refuses settings the checkpoint cannot continue with
        if changed:
            update_stored_config(run_dir, stored, config)

    members: list[MemberResult] = []
    for g in groups:
        label = ",".join(str(s) for s in g.seeds)
        if not g.finished:
            try:
                g.run(progress, label)
            except (KeyboardInterrupt, TrainingDiverged) as exc:
                if isinstance(exc, NonFiniteStart) and not resume and not members:
                    _remove_run(run_dir, seeds)  # nothing trained: nothing to block a rerun
                    raise
                # leave a loadable run: best model so far, history and metrics
                for k, s in enumerate(g.seeds):
                    finish_member(g, k, s, run_dir, K, train_np.count, test_np.count,
                                  interrupted=isinstance(exc, KeyboardInterrupt))
                raise
        for k, s in enumerate(g.seeds):
            members.append(finish_member(g, k, s, run_dir, K, train_np.count, test_np.count))

    metrics = aggregate_metrics(members, mode, base)
    if K > 1:
        ckpt.atomic_write_json(run_dir / "metrics.json", metrics, record=True)
        ckpt.write_history(run_dir / "history.csv", mean_history([m.history for m in members]),
                          record=True)
        loss_plot(run_dir, [m.history for m in members], [f"seed {m.seed}" for m in members])
    return TrainResult(run_dir=run_dir, config=config, members=members, metrics=metrics)


