"""The stages of a task run, each writing under ``OUT/<stage>/`` with a ``done.json`` of the
settings that made it, so that a second call with the same settings skips finished stages
(:class:`Stages`); here the data and the training stages, the measuring ones (predict, floor,
modes, analyze) in :mod:`.measure_stages`."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.exact.serialize import spec_known_input
from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.bridge.tasks.plan import Plan, Variant, data_step, own_substeps
from softpinn.errors import UserError
from softpinn.files import KEEP
from softpinn.files import write_json as write_json_file
from softpinn.learn import (
    ModelConfig,
    TrainConfig,
    load_dataset,
    mass_scale,
    resolve_momenta,
    train,
)
from softpinn.symbolic import make_dataset, resample, select_trajectories, write_dataset

# ---------------------------------------------------------------------------------- stages


def write_json(path: Path, obj: Any) -> None:
    # KEEP: a reused stage gives back the inf it stored (softpinn.files' one exception)
    write_json_file(path, obj, nonfinite=KEEP, end="", default=jsonable)


def jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    raise TypeError(f"not JSON serialisable: {type(x)}")


#: How stage records name paths inside the output folder, so that the folder can be moved,
#: copied or reached from another working directory and its finished stages still found.
OUT_MARK = "$OUT"


class Stages:
    """Runs named stages once: a stage whose ``done.json`` holds the same settings is skipped.

    Paths inside the output folder are stored as ``$OUT/<relative path>`` in the settings and
    results of ``done.json`` and given back rooted at the current output folder."""

    def __init__(self, out: Path, log: Callable[[str], None]):
        self.out = out
        self.log = log
        self.seconds: dict[str, float] = {}  # per stage, as measured when it ran
        self.ran: set[str] = set()  # the stages this call ran (not reused)
        self.quiet: set[str] = set()  # reused without a log line (run by this call's workers)
        self._root = os.path.abspath(out)

    def portable(self, x: Any) -> Any:
        """``x`` (JSON-like) with every path string inside the output folder as ``$OUT/...``."""
        if isinstance(x, dict):
            return {k: self.portable(v) for k, v in x.items()}
        if isinstance(x, list):
            return [self.portable(v) for v in x]
        if isinstance(x, str) and os.sep in x and not x.startswith(OUT_MARK):
            a = os.path.abspath(x)
            if a == self._root or a.startswith(self._root + os.sep):
                return OUT_MARK + a[len(self._root):].replace(os.sep, "/")
        return x

    def rooted(self, x: Any) -> Any:
        """The inverse of :meth:`portable`: ``$OUT/...`` strings as paths in this output folder."""
        if isinstance(x, dict):
            return {k: self.rooted(v) for k, v in x.items()}
        if isinstance(x, list):
            return [self.rooted(v) for v in x]
        if isinstance(x, str) and (x == OUT_MARK or x.startswith(OUT_MARK + "/")):
            return str(self.out.joinpath(*x[len(OUT_MARK) + 1:].split("/")))
        return x

    def finished(self, name: str, settings: Mapping[str, Any]) -> dict | None:
        """The stored record (settings, result, seconds) of stage ``name`` if it finished
        with these settings, else None."""
        done = self.out / name / "done.json"
        if not done.is_file():
            return None
        stored = json.loads(done.read_text())
        settings = self.portable(json.loads(json.dumps(settings, default=jsonable)))
        # records written before paths were stored as $OUT/... are read the same way
        return stored if self.portable(stored.get("settings")) == settings else None

    def run(self, name: str, settings: Mapping[str, Any], fn: Callable[[Path], Any]) -> Any:
        folder = self.out / name
        done = folder / "done.json"
        settings = self.portable(json.loads(json.dumps(settings, default=jsonable)))
        stored = self.finished(name, settings)
        if stored is not None:
            if name not in self.quiet:
                self.log(f"[{name}] done before, skipped")
            self.seconds[name] = float(stored.get("seconds", 0.0))
            return self.rooted(self.portable(stored["result"]))
        folder.mkdir(parents=True, exist_ok=True)
        self.log(f"[{name}] ...")
        t0 = time.perf_counter()
        result = fn(folder)
        seconds = time.perf_counter() - t0
        result = self.portable(json.loads(json.dumps(result, default=jsonable)))
        write_json(done, {"settings": settings, "result": result, "seconds": seconds})
        self.seconds[name] = seconds
        self.ran.add(name)
        self.log(f"[{name}] {seconds:.1f} s")
        return self.rooted(result)


# ---------------------------------------------------------------------------------- data


def stage_data(spec, plan: Plan, folder: Path) -> dict:
    """Simulate the plan's data sets and write each variant's physics and black-box files
    (training trajectories and the test ones)."""
    out: dict[str, Any] = {"variants": {}}
    sources = {v.source for v in plan.variants}
    made = {}
    if "cvodes" in sources:
        made["cvodes"] = make_dataset(spec, data=plan.data, integrator="cvodes")
    if "rk4" in sources:
        fs = plan.fixed_step
        made["rk4"] = make_dataset(spec, data=plan.data, integrator="rk4", dt=fs["dt"],
                                   rate=fs["rate"], duration=fs["duration"],
                                   trajectories=fs["trajectories"])
    for variant in plan.variants:
        arrays = made[variant.source]
        if variant.rate is not None and variant.rate != arrays.meta["rate"]:
            arrays = resample(arrays, variant.rate)
        splits = arrays.meta["splits"]
        files = {}
        for role, train_ids in (("physics", splits["train"]),
                                ("blackbox", splits["blackbox_train"])):
            sel = select_trajectories(arrays, list(train_ids) + list(splits["test"]))
            path = folder / f"{variant.name}-{role}.npz"
            write_dataset(path, sel, force=True)
            files[role] = {"path": str(path), "train": list(map(int, train_ids)),
                           "test": list(map(int, splits["test"])),
                           "samples": int(sum(int((sel.traj == i).sum()) for i in train_ids))}
        files["rate"] = float(arrays.meta["rate"])
        files["timestep"] = 1.0 / float(arrays.meta["rate"])
        out["variants"][variant.name] = files
    return out


# -------------------------------------------------------------------------------- training


def _model_config(spec, plan: Plan, kind: str, data, train_ids):
    """The model of ``kind``; ``data`` (a learn Dataset) and ``train_ids`` set mass_init."""

    m = plan.models[kind]
    mass_init = None
    if m.mass_init == "data":
        # Started at M⁻¹ ~ I, task4's Hamiltonian network (true M⁻¹ ~ 200) fell at once into
        # M⁻¹ ≈ 0, q̇ ≈ 0 (a test loss stuck at 4.6e-5) and never left it.
        mass_init = mass_scale(data, kind, train_ids)
    extra = {}
    if kind != "blackbox":
        if m.damping_form is not None:
            extra["damping_form"] = str(m.damping_form)
        if m.known_input:  # the recipe's known actuator model: this spec's own A(q)
            extra.update(input_form="known", known_input=spec_known_input(spec)[0])
    return ModelConfig(
        kind=kind, n=spec.n, m=spec.m, mass=tuple(m.mass), potential=tuple(m.potential),
        damping=tuple(m.damping), input=tuple(m.input), hidden=tuple(m.hidden),
        dtype="float32" if plan.float32 else "float64", mass_init=mass_init, **extra,
    )


def _same_run(run_dir: Path, tc) -> bool:
    """Whether ``run_dir`` holds a checkpoint of a run with exactly the settings ``tc`` (one
    interrupted before it finished is resumed; one of other settings is trained afresh)."""
    if not ((run_dir / "checkpoint.eqx").is_file() or any(run_dir.glob("seed-*/checkpoint.eqx"))):
        return False
    try:
        stored = json.loads((run_dir / "config.json").read_text())["train"]
        return TrainConfig.from_dict(stored) == tc
    except (OSError, ValueError, KeyError, TypeError):
        return False


def variant_model(plan: Plan, variant: Variant, kind: str,
                  files: Mapping[str, Any] | None = None) -> ModelBudget:
    """The budget of model ``kind`` as trained on ``variant``: its own sub-steps, if any, and,
    for a budget marked ``equal_steps``, as many optimizer steps as on ``physics_samples``
    pairs where the variant's training data (``files``) hold fewer (task5's 50 Hz data: 24,000
    samples, so 375 epochs where the others take 200). A network with a ``max_step`` of its
    own (``[training.<network>]``) takes its sub-steps from that, not from the variant's. The
    result has neither ``max_step`` nor ``equal_steps`` (both applied)."""
    m = plan.models[kind]
    substeps, epochs = m.substeps, m.epochs
    if m.max_step is not None:
        substeps = own_substeps(m, data_step(plan, variant))
    elif variant.substeps is not None:
        substeps = max(int(m.substeps), variant.substeps)
    target = plan.physics_samples
    if m.equal_steps and target and files is not None and kind != "blackbox":
        have = int(files["physics"]["samples"])
        if 0 < have < target:
            epochs = math.ceil(int(m.epochs) * target / have)
    return dataclasses.replace(m, substeps=substeps, epochs=epochs, max_step=None,
                               equal_steps=None)


def stage_train(spec, plan: Plan, kind: str, m: ModelBudget, files: dict, folder: Path,
                progress, model_changes: Mapping[str, Any] | None = None) -> dict:
    """Train model ``kind`` of the plan with budget ``m`` (a variant's: :func:`variant_model`);
    ``model_changes``: fields of its ModelConfig set otherwise (e.g. ``input_form="known"``
    with ``known_input``, the known-A study). Settings the budget leaves out take
    ``TrainConfig``'s defaults."""
    role = "blackbox" if kind == "blackbox" else "physics"
    f = files[role]
    data = load_dataset(f["path"])  # read once: for mass_init and for training
    epochs = int(m.epochs)
    tc = TrainConfig(
        model=dataclasses.replace(_model_config(spec, plan, kind, data, f["train"]),
                                  **dict(model_changes or {})),
        epochs=epochs,
        batch_size=plan.batch_size,
        lr=float(m.lr),
        seed=0,
        seeds=plan.seeds,
        test_trajectories=tuple(f["test"]),
        samples=plan.physics_samples if role == "physics" else None,
        lbfgs_steps=int(m.lbfgs),
        eval_every=max(1, epochs // 50),
        checkpoint_every=max(1, epochs // 10),
        **m.integration(),
        **m.train_settings(),
    )
    # as train() stores it (a Hamiltonian network's momenta "auto" decided for these data), so
    # that an interrupted run's config.json compares equal and the run is resumed
    tc = resolve_momenta(tc, data)
    run_dir = folder / "run"
    resume = _same_run(run_dir, tc)
    try:
        res = train(data, tc, run_dir, progress=progress, force=not resume, resume=resume)
    except UserError:
        if not resume:
            raise
        # e.g. the data set was simulated again: start over
        res = train(data, tc, run_dir, progress=progress, force=True)
    return {"run": str(run_dir), "metrics": res.metrics, "config": tc.to_dict(),
            "samples": res.metrics.get("train_pairs", f["samples"]), "epochs": tc.epochs}
