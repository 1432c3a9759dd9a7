"""The paper's five tasks end to end: ``softpinn reproduce TASK``.

One call runs the whole study of a task (Section III-B, Section IV, Appendix B):

1. **data**: simulate the preset's trajectories with the paper's settings (``[data]``), split
   them as the paper does (physics-model training, black-box training, test);
2. **train**: the physics model(s) of the task (Task 1, 2: Lagrangian; Task 3: Hamiltonian;
   Task 4: Lagrangian and Hamiltonian; Task 5: Lagrangian on the fixed-step and on the 50, 100,
   1000 Hz data) and the black-box baseline, which gets more data as in the paper;
3. **predict**: one-step test error and rollouts over the paper's horizon (2.7 s, 5 s, 10 s),
   long rollouts (Fig. 9) and rollouts with another step size (Figs. 24-25);
4. **analyze**: learned against true M, M^-1, D, G, A at the paper's table q and at q sampled
   in the data's range, with the transforms of :mod:`bridge.transforms`;
5. **report**: ``report.md`` with Table III's row for the task beside ours, the matrix
   summaries and the figures.

Every stage writes its results under ``OUT/<stage>/`` and a ``done.json`` holding the settings
that made them; a second call with the same settings skips finished stages, so an interrupted
run loses at most the stage it was in (training itself resumes from its last checkpoint).

``quick=True`` runs the same pipeline on small settings (few short trajectories, small nets,
few epochs) in a minute or two; tests and notebooks use it. Full runs use the paper's network
sizes and data, with our own, shorter training budgets (the recipe's ``[training.full.*]``
tables, :mod:`symbolic.recipe`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UserError

TASKS = ("task1", "task2", "task3", "task4", "task5")
PHYSICS_KINDS = ("lagrangian", "hamiltonian")

#: The paper's smallest networks (4 wide for Task 1) did not reach its losses in our budgets;
#: mass and potential networks get at least this width (Table III's sizes are in the report).
MIN_WIDTH = 32

#: λ of the one-step errors a report shows (train, test, floor, no forces): the same for every
#: model of a task whatever λ it trained with, so the columns compare.
REPORT_WEIGHT = 1.0

@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of one ``reproduce`` call (everything else comes from the task's preset)."""

    task: str
    quick: bool = False
    seeds: int = 1
    epochs: int | None = None  # overrides every model's epochs
    lbfgs_steps: int | None = None  # overrides every model's L-BFGS iterations
    float32: bool = False
    analysis_points: int | None = None  # sampled q for the analysis (default 200, quick 40)

    def __post_init__(self):
        if self.task not in TASKS:
            raise UserError(f"task: expected one of {', '.join(TASKS)}, got {self.task!r}")
        if not isinstance(self.seeds, int) or self.seeds < 1:
            raise UserError(f"--seeds must be an integer >= 1, got {self.seeds!r}")
        if self.epochs is not None and (not isinstance(self.epochs, int) or self.epochs < 1):
            raise UserError(f"--epochs must be an integer >= 1, got {self.epochs!r}")
        if self.lbfgs_steps is not None and self.lbfgs_steps < 0:
            raise UserError(f"--lbfgs-steps must be >= 0, got {self.lbfgs_steps!r}")


# ------------------------------------------------------------------------------------ plan


@dataclass(frozen=True)
class Variant:
    """One data set and the models trained on it (Task 5 has four)."""

    name: str  # "main", or for task5 "fixed_0.0002s", "50Hz", "100Hz", "1000Hz"
    source: str  # "cvodes" or "rk4" (the simulated file it comes from)
    rate: float | None  # resample the source to this rate (None: as simulated)
    models: tuple[str, ...]
    substeps: int | None = None  # RK4 steps per data interval (None: the models' own)


@dataclass(frozen=True)
class Plan:
    """What a task run does: data settings, variants, and per-model training settings."""

    task: str
    quick: bool
    data: Mapping[str, Any]
    fixed_step: Mapping[str, Any] | None
    variants: tuple[Variant, ...]
    models: Mapping[str, Mapping[str, Any]]
    batch_size: int
    horizon: float
    long_horizon: float
    other_dt: float | None
    analysis_points: int
    physics_samples: int | None
    seeds: int
    float32: bool

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self), default=list))


def make_plan(spec, config: ReproduceConfig) -> Plan:
    """The plan of a task run from its spec's recipe (``[training]``, :mod:`symbolic.recipe`)
    and ``[data]`` tables, and the call's settings. A ``[data]`` table with ``rates`` gives one
    variant per rate (the black box on ``blackbox_rates`` only), and with ``fixed_step_dt`` one
    more on fixed-step RK4 data; otherwise one variant on the data as simulated."""
    task, quick = config.task, config.quick
    recipe = spec.recipe
    data = dict(spec.data)
    physics = recipe.physics
    horizon = recipe.prediction_horizon
    fixed_step = None
    if quick:
        data.update(train_trajectories=3, test_trajectories=2, blackbox_train_trajectories=4)
        data["duration"] = recipe.quick["duration"]
        data.pop("trajectories", None)
        horizon = min(horizon, data["duration"] * 0.6)
        if "rates" in recipe.quick:
            data["rates"] = list(recipe.quick["rates"])
        if "fixed_step_train_trajectories" in recipe.quick:
            data["fixed_step_train_trajectories"] = recipe.quick["fixed_step_train_trajectories"]
    if "rates" in data:
        variants = []
        if "fixed_step_dt" in data:
            dt = float(data["fixed_step_dt"])
            q = recipe.quick if quick else {}
            fixed_step = {
                "dt": dt,
                "rate": float(q.get("fixed_step_rate", data.get("fixed_step_rate", 1.0 / dt))),
                "duration": float(q.get("fixed_step_duration", data["duration"] if quick
                                        else min(10.0, float(data["duration"])))),
                "trajectories": int(q.get("fixed_step_trajectories",
                                          data.get("fixed_step_trajectories", 5))),
            }
            variants.append(Variant(f"fixed_{dt:g}s", "rk4", None, physics + ("blackbox",)))
        black = recipe.blackbox_rates
        for r in (float(r) for r in data["rates"]):
            kinds = physics + (("blackbox",) if black is None or r in black else ())
            sub = (math.ceil(1.0 / r / recipe.max_step - 1e-9)
                   if recipe.max_step is not None else None)
            variants.append(Variant(f"{r:g}Hz", "cvodes", r, kinds,
                                    sub if sub and sub > 1 else None))
        variants = tuple(variants)
    else:
        variants = (Variant("main", "cvodes", None, physics + ("blackbox",)),)
    models: dict[str, dict[str, Any]] = {}
    for kind in physics + ("blackbox",):
        budget = recipe.full.get(kind, {})
        net = kind if kind != "blackbox" else physics[0]
        if quick:
            m = dict(
                mass=(16, 2), potential=(16, 2), damping=(8, 2), input=(8, 2), hidden=(32, 2),
                epochs=int(recipe.quick["epochs"]), lbfgs=0, lr=3e-3,
            )
        else:
            m = dict(
                mass=recipe.network(net, "mass", (64, 3)),
                potential=recipe.network(net, "potential", (64, 3)),
                damping=recipe.network(net, "damping", (16, 2)),
                input=recipe.network(net, "input", (16, 2)),
                hidden=recipe.network("blackbox", "hidden", (128, 3)),
                epochs=int(budget.get("epochs", 1000)), lbfgs=int(budget.get("lbfgs_steps", 0)),
                lr=float(budget.get("lr", 2e-3)),
            )
            for name in ("mass", "potential"):
                m[name] = (max(m[name][0], MIN_WIDTH), m[name][1])
        m["paper_epochs"] = recipe.network(kind, "epochs")
        m.update(substeps=recipe.substeps, input_hold=recipe.input_hold)
        # the loss a network learns from (eq. 8/9 unless the recipe says otherwise)
        m.update({k: recipe.networks.get(kind, {})[k] for k in ("loss", "loss_weight",
                                                                "accel_labels")
                  if k in recipe.networks.get(kind, {})})
        if kind == "hamiltonian":
            m["mass_init"] = "data"  # M⁻¹'s initial diagonal from the data (learn.mass_scale)
        m["equal_steps"] = bool(budget.get("equal_steps", False)) and not quick
        if config.epochs is not None:
            m["epochs"] = config.epochs
            m["equal_steps"] = False
        if config.lbfgs_steps is not None:
            m["lbfgs"] = config.lbfgs_steps
        models[kind] = m
    other_dt = recipe.other_dt
    if other_dt is None:
        rate = float(data.get("rate", max(data.get("rates", [100.0]))))
        other_dt = 2.0 / rate
    return Plan(
        task=task,
        quick=quick,
        data=data,
        fixed_step=fixed_step,
        variants=variants,
        models=models,
        batch_size=recipe.batch_size,
        horizon=horizon,
        long_horizon=min(3 * horizon, float(data["duration"])),
        other_dt=other_dt,
        analysis_points=config.analysis_points or (40 if quick else 200),
        physics_samples=None if quick else data.get("physics_samples"),
        seeds=config.seeds,
        float32=config.float32,
    )


# ---------------------------------------------------------------------------------- stages


def _write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=2, default=_jsonable))
    tmp.replace(path)


def _jsonable(x):
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


class _Stages:
    """Runs named stages once: a stage whose ``done.json`` holds the same settings is skipped.

    Paths inside the output folder are stored as ``$OUT/<relative path>`` in the settings and
    results of ``done.json`` and given back rooted at the current output folder."""

    def __init__(self, out: Path, log: Callable[[str], None]):
        self.out = out
        self.log = log
        self.seconds: dict[str, float] = {}  # per stage, as measured when it ran
        self.ran: set[str] = set()  # the stages this call ran (not reused)
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

    def run(self, name: str, settings: Mapping[str, Any], fn: Callable[[Path], Any]) -> Any:
        folder = self.out / name
        done = folder / "done.json"
        settings = self.portable(json.loads(json.dumps(settings, default=_jsonable)))
        if done.is_file():
            stored = json.loads(done.read_text())
            # records written before paths were stored as $OUT/... are read the same way
            if self.portable(stored.get("settings")) == settings:
                self.log(f"[{name}] done before, skipped")
                self.seconds[name] = float(stored.get("seconds", 0.0))
                return self.rooted(self.portable(stored["result"]))
        folder.mkdir(parents=True, exist_ok=True)
        self.log(f"[{name}] ...")
        t0 = time.perf_counter()
        result = fn(folder)
        seconds = time.perf_counter() - t0
        result = self.portable(json.loads(json.dumps(result, default=_jsonable)))
        _write_json(done, {"settings": settings, "result": result, "seconds": seconds})
        self.seconds[name] = seconds
        self.ran.add(name)
        self.log(f"[{name}] {seconds:.1f} s")
        return self.rooted(result)


@dataclass
class ReproduceResult:
    """What :func:`reproduce` returns: paths and every figure it measured."""

    config: ReproduceConfig
    out_dir: Path
    report: Path
    plan: Plan
    results: dict = field(repr=False)
    seconds: float = 0.0


def reproduce(
    config: ReproduceConfig | str,
    out_dir: str | Path,
    *,
    log: Callable[[str], None] | None = None,
    progress: Callable[[dict], None] | None = None,
) -> ReproduceResult:
    """Run a paper task end to end into ``out_dir`` (see the module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from softpinn.symbolic.spec import load_spec

    if isinstance(config, str):
        config = ReproduceConfig(task=config)
    log = log or (lambda s: None)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    spec = load_spec(config.task)
    plan = make_plan(spec, config)
    _write_json(out / "plan.json", plan.to_dict())
    stages = _Stages(out, log)

    data_settings = {"plan_data": plan.data, "fixed": plan.fixed_step}
    data = stages.run("data", data_settings, lambda d: _stage_data(spec, plan, d))
    results: dict[str, Any] = {"data": data, "variants": {}}
    credit: dict[str, float] = {}  # training time of runs resumed when already finished
    for variant in plan.variants:
        vres: dict[str, Any] = {"models": {}}
        files = data["variants"][variant.name]
        for kind in variant.models:
            key = f"{variant.name}/{kind}"
            mplan = variant_model(plan, variant, kind, files)
            # the data settings too: a data set simulated again under the same file name
            # must not leave models trained on the old one
            settings = {"model": mplan, "files": files, "data": data_settings,
                        "batch": plan.batch_size, "seeds": plan.seeds, "float32": plan.float32,
                        "samples": plan.physics_samples if kind != "blackbox" else None}
            name = f"train/{variant.name}/{kind}"
            tr = stages.run(name, settings,
                            lambda d, k=kind, f=files, m=mplan: _stage_train(
                                spec, plan, k, m, f, d, progress))
            # a finished run found again takes no time now: count the time it trained
            trained = sum(float(m.get("seconds", 0.0)) for m in tr["metrics"].get("members", []))
            credit[name] = max(0.0, trained - stages.seconds[name])
            pr = stages.run(f"predict/{variant.name}/{kind}",
                            {"train": settings, "horizon": plan.horizon,
                             "long": plan.long_horizon, "dt": plan.other_dt},
                            lambda d, k=kind, f=files, t=tr: _stage_predict(plan, k, f, t, d))
            fl = stages.run(f"floor/{variant.name}/{kind}",
                            {"files": files, "data": data_settings, "no_forces": True,
                             "integration": _integration(mplan),
                             "state": "momentum" if kind == "hamiltonian" else "velocity"},
                            lambda d, k=kind, f=files, m=mplan: _stage_floor(spec, k, m, f))
            mo = stages.run(f"modes/{variant.name}/{kind}", {"train": settings},
                            lambda d, k=kind, f=files, t=tr: _stage_modes(spec, k, f, t))
            entry = {"train": tr, "predict": pr, "floor": fl, "modes": mo}
            if kind != "blackbox":
                entry["analyze"] = stages.run(
                    f"analyze/{variant.name}/{kind}",
                    {"train": settings, "points": plan.analysis_points, "every_seed": True,
                     "force_samples": plan.analysis_points * 10, "accelerations": 3},
                    lambda d, t=tr, f=files: _stage_analyze(spec, plan, t, f, d),
                )
            vres["models"][kind] = entry
            log(f"{key}: test {pr['test_error']['mean']:.3e}, rollout "
                f"{pr['prediction_error']['mean']:.3e} over {plan.horizon:g} s")
        results["variants"][variant.name] = vres
    # the run's time is that of its stages when they ran (a call that reuses finished stages
    # reports what they took then), plus this call's own overhead
    seconds = sum(stages.seconds.values()) + sum(credit.values()) + (
        time.perf_counter() - t_start - sum(
            v for k, v in stages.seconds.items() if k in stages.ran))
    results["stage_seconds"] = {k: v + credit.get(k, 0.0) for k, v in stages.seconds.items()}
    from .report import write_task_report

    report = write_task_report(spec, plan, results, out, seconds=seconds,
                               machine=machine_description())
    _write_json(out / "results.json", {
        "task": plan.task, "quick": plan.quick, "seconds": seconds,
        "machine": machine_description(), "results": results,
    })
    log(f"report: {report}")
    return ReproduceResult(config, out, report, plan, results, seconds)


def notebook_run(task: str) -> tuple[ReproduceConfig, Path]:
    """The configuration and output folder a task notebook uses, from the environment:
    ``SOFTPINN_QUICK`` ("0" for the full run; default quick), ``SOFTPINN_OUT`` (default
    ``runs/notebooks``), and ``SOFTPINN_EPOCHS`` / ``SOFTPINN_LBFGS`` to override the budgets
    (the test suite runs the notebooks on the shortest budgets)."""
    import os

    quick = os.environ.get("SOFTPINN_QUICK", "1") != "0"
    epochs = os.environ.get("SOFTPINN_EPOCHS")
    lbfgs = os.environ.get("SOFTPINN_LBFGS")
    config = ReproduceConfig(
        task, quick=quick, epochs=int(epochs) if epochs else None,
        lbfgs_steps=int(lbfgs) if lbfgs else None,
    )
    root = Path(os.environ.get("SOFTPINN_OUT", "runs/notebooks"))
    return config, root / f"{task}{'-quick' if quick else ''}"


def machine_description() -> str:
    import os

    return f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}, " \
           f"Python {platform.python_version()}"


# ---------------------------------------------------------------------------------- data


def _stage_data(spec, plan: Plan, folder: Path) -> dict:
    from softpinn.symbolic.datasets import (
        make_dataset,
        resample,
        select_trajectories,
        write_dataset,
    )

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
    from softpinn.learn.data import mass_scale
    from softpinn.learn.models import ModelConfig

    m = plan.models[kind]
    mass_init = None
    if m.get("mass_init") == "data":
        # Started at M⁻¹ ~ I, task4's Hamiltonian network (true M⁻¹ ~ 200) fell at once into
        # M⁻¹ ≈ 0, q̇ ≈ 0 (a test loss stuck at 4.6e-5) and never left it.
        mass_init = mass_scale(data, kind, train_ids)
    return ModelConfig(
        kind=kind, n=spec.n, m=spec.m, mass=tuple(m["mass"]), potential=tuple(m["potential"]),
        damping=tuple(m["damping"]), input=tuple(m["input"]), hidden=tuple(m["hidden"]),
        dtype="float32" if plan.float32 else "float64", mass_init=mass_init,
    )


def _same_run(run_dir: Path, tc) -> bool:
    """Whether ``run_dir`` holds a checkpoint of a run with exactly the settings ``tc`` (one
    interrupted before it finished is resumed; one of other settings is trained afresh)."""
    from softpinn.learn.train import TrainConfig

    if not ((run_dir / "checkpoint.eqx").is_file() or any(run_dir.glob("seed-*/checkpoint.eqx"))):
        return False
    try:
        stored = json.loads((run_dir / "config.json").read_text())["train"]
        return TrainConfig.from_dict(stored) == tc
    except (OSError, ValueError, KeyError, TypeError):
        return False


def variant_model(plan: Plan, variant: Variant, kind: str,
                  files: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The plan of model ``kind`` as trained on ``variant``: its own sub-steps, if any, and,
    for a budget marked ``equal_steps``, as many optimizer steps as on ``physics_samples``
    pairs where the variant's training data (``files``) hold fewer (task5's 50 Hz data: 24,000
    samples, so 375 epochs where the others take 200)."""
    m = dict(plan.models[kind])
    if variant.substeps is not None:
        m["substeps"] = max(int(m["substeps"]), variant.substeps)
    target = plan.physics_samples
    if m.pop("equal_steps", False) and target and files is not None and kind != "blackbox":
        have = int(files["physics"]["samples"])
        if 0 < have < target:
            m["epochs"] = math.ceil(int(m["epochs"]) * target / have)
    return m


def _stage_train(spec, plan: Plan, kind: str, m: Mapping[str, Any], files: dict, folder: Path,
                 progress) -> dict:
    from softpinn.learn.data import load_dataset
    from softpinn.learn.errors import UserError as LearnUserError
    from softpinn.learn.train import TrainConfig, train

    role = "blackbox" if kind == "blackbox" else "physics"
    f = files[role]
    data = load_dataset(f["path"])  # read once: for mass_init and for training
    tc = TrainConfig(
        model=_model_config(spec, plan, kind, data, f["train"]),
        epochs=int(m["epochs"]),
        batch_size=plan.batch_size,
        lr=float(m["lr"]),
        seed=0,
        seeds=plan.seeds,
        test_trajectories=tuple(f["test"]),
        samples=plan.physics_samples if role == "physics" else None,
        lbfgs_steps=int(m["lbfgs"]),
        substeps=int(m["substeps"]),
        input_hold=str(m["input_hold"]),
        loss=str(m.get("loss", "pair")),
        accel_labels=str(m.get("accel_labels", "recorded")),
        loss_weight=float(m.get("loss_weight", 1.0)),
        eval_every=max(1, int(m["epochs"]) // 50),
        checkpoint_every=max(1, int(m["epochs"]) // 10),
    )
    run_dir = folder / "run"
    resume = _same_run(run_dir, tc)
    try:
        res = train(data, tc, run_dir, progress=progress, force=not resume, resume=resume)
    except LearnUserError:
        if not resume:
            raise
        # e.g. the data set was simulated again: start over
        res = train(data, tc, run_dir, progress=progress, force=True)
    return {"run": str(run_dir), "metrics": res.metrics, "config": tc.to_dict(),
            "samples": res.metrics.get("train_pairs", f["samples"]), "epochs": tc.epochs}


# ------------------------------------------------------------------------------- prediction


def _stage_predict(plan: Plan, kind: str, files: dict, trained: dict, folder: Path) -> dict:
    """Train and test one-step errors, rollouts over the horizon and a long horizon (one
    rollout: the first part is the horizon's), and rollouts with another step size."""
    import jax.numpy as jnp

    from softpinn.learn.data import load_dataset, make_pairs, trajectories
    from softpinn.learn.losses import Pairs
    from softpinn.learn.predict import evaluate, one_step_errors, rollouts
    from softpinn.learn.train import load_ensemble

    f = files["blackbox" if kind == "blackbox" else "physics"]
    data = load_dataset(f["path"])
    test = f["test"]
    per_seed = []
    for run in load_ensemble(trained["run"]):
        tc, cfg = run.train_config, run.model_config
        kw = dict(substeps=tc.substeps, input_hold=tc.input_hold)
        long = evaluate(run.model, data, test, horizon=plan.long_horizon,
                        loss_weight=REPORT_WEIGHT, **kw)
        main = [_truncated_error(r, plan.horizon) for r in long.rollouts]
        other = rollouts(run.model, trajectories(data, test, state=cfg.state_kind),
                         horizon=plan.horizon, dt=plan.other_dt, **kw)
        pnp = make_pairs(data, f["train"], state=cfg.state_kind,
                         samples=min(20000, f["samples"]), seed=0)
        dtype = jnp.dtype(cfg.dtype)
        pairs = Pairs(*(jnp.asarray(a, dtype) for a in pnp[:5]), None)
        train_err = one_step_errors(run.model, pairs, weight=REPORT_WEIGHT, **kw)
        per_seed.append({"seed": run.seed, "long": long, "main": np.asarray(main),
                         "other": np.asarray([r["error"] for r in other]),
                         "train": train_err, "other_rollouts": other})
    first = per_seed[0]
    arrays = {}
    for prefix, r in (("long", first["long"].rollouts[0]), ("other", first["other_rollouts"][0])):
        arrays.update({f"{prefix}_t": r["t"], f"{prefix}_q_true": r["q_true"],
                       f"{prefix}_q_pred": r["q_pred"]})
    r = first["long"].rollouts[0]
    keep = r["t"] - r["t"][0] <= plan.horizon * (1 + 1e-12) + 1e-12
    arrays.update({"main_t": r["t"][keep], "main_q_true": r["q_true"][keep],
                   "main_q_pred": r["q_pred"][keep]})
    np.savez(folder / "rollouts.npz", **arrays)

    def stat(key, pick=lambda x: x):
        # a rollout that blew up has error inf: the mean and std are then inf (not NaN)
        vals = [np.asarray(pick(p[key]), float) for p in per_seed]
        with np.errstate(invalid="ignore", over="ignore"):
            means = [float(np.mean(v)) for v in vals]
            stds = [float(np.std(v)) if np.all(np.isfinite(v)) else math.inf for v in vals]
            out = {"mean": float(np.mean(means)), "std": float(np.mean(stds))}
            if len(per_seed) > 1:
                spread = float(np.std(means)) if np.all(np.isfinite(means)) else math.inf
                out["seeds"] = {"mean": float(np.mean(means)), "std": spread}
        return out

    test_err = stat("long", lambda res: np.asarray([res.one_step_error["mean"]]))
    test_err["std"] = float(np.mean([p["long"].one_step_error["std"] for p in per_seed]))
    return {
        "train_error": stat("train"),
        "test_error": test_err,
        "prediction_error": {**stat("main"), "horizon_s": plan.horizon},
        "long_prediction_error": {
            **stat("long", lambda res: np.asarray(res.rollout_errors)),
            "horizon_s": plan.long_horizon,
        },
        "other_dt_prediction_error": {**stat("other"), "dt": plan.other_dt,
                                      "horizon_s": plan.horizon},
        "rollout_errors": first["main"].tolist(),
        "trajectories": list(map(int, test)),
        "seeds": [p["seed"] for p in per_seed],
    }


def _integration(m: Mapping[str, Any]) -> dict[str, Any]:
    return {"substeps": int(m["substeps"]), "input_hold": str(m["input_hold"])}


def _stage_floor(spec, kind: str, m: Mapping[str, Any], files: dict) -> dict:
    """On the test pairs: the true model's one-step loss, stepped as the model is (the floor),
    and the loss of a model that learned no forces (floors.py)."""
    from softpinn.learn.data import load_dataset, make_pairs
    from softpinn.symbolic.model import TrueModel

    from .floors import drift_baseline, integration_floor

    f = files["blackbox" if kind == "blackbox" else "physics"]
    state = "momentum" if kind == "hamiltonian" else "velocity"
    data = load_dataset(f["path"])
    pairs = make_pairs(data, f["test"], state=state)
    err = integration_floor(TrueModel(spec), pairs, state=state, weight=REPORT_WEIGHT,
                            **_integration(m))
    qd0 = make_pairs(data, f["test"], state="velocity").x0[:, spec.n:]
    drift = drift_baseline(pairs, qd0, state=state, weight=REPORT_WEIGHT)
    with np.errstate(invalid="ignore", over="ignore"):
        return {"mean": float(np.mean(err)), "std": float(np.std(err)), "pairs": len(err),
                "state": state, **_integration(m),
                "no_forces": float(np.mean(drift))}


def _stage_modes(spec, kind: str, files: dict, trained: dict) -> dict:
    """Eigenvalues of the true and the learned (first seed) dynamics linearised at rest at the
    training data's mean q with its mean input (modes.py)."""
    from softpinn.learn.data import load_dataset
    from softpinn.learn.train import load_ensemble
    from softpinn.symbolic.model import TrueModel

    from .modes import modes

    f = files["blackbox" if kind == "blackbox" else "physics"]
    data = load_dataset(f["path"])
    keep = np.isin(data.traj, np.asarray(f["train"]))
    run = load_ensemble(trained["run"])[0]
    return modes(TrueModel(spec), run.model, data.q[keep].mean(axis=0),
                 data.u[keep].mean(axis=0) if spec.m else None)


def _truncated_error(rollout: dict, horizon: float) -> float:
    """The rollout error (mean over samples after t0 of ||q - q_hat||^2) over the first
    ``horizon`` seconds of a longer rollout."""
    t = rollout["t"]
    keep = t - t[0] <= horizon * (1 + 1e-12) + 1e-12
    d = rollout["q_pred"][keep][1:] - rollout["q_true"][keep][1:]
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.mean(np.sum(d * d, axis=1)))
    return err if math.isfinite(err) else float("inf")


# --------------------------------------------------------------------------------- analysis


def _stage_analyze(spec, plan: Plan, trained: dict, files: dict, folder: Path) -> dict:
    """Every seed's learned matrices against the true ones at the same q: the first seed's
    analysis in ``folder`` (the report's headline), each further seed's in ``folder/seed-S``."""
    from softpinn.learn.data import load_dataset
    from softpinn.learn.train import load_ensemble
    from softpinn.symbolic.model import TrueModel

    from .analysis import analysis_q, analyze, summary_numbers, write_report
    from .forces import data_samples

    true = TrueModel(spec)
    q, k = analysis_q(spec, count=plan.analysis_points, seed=0)
    runs = load_ensemble(trained["run"])
    # the force terms along the training trajectories the models learned from (every member
    # trained on the same data and split, so one draw of samples serves them all)
    info = runs[0].info
    # the data file as this output folder holds it (the run's config.json has the path it
    # had when it trained, which moves with the folder)
    samples = data_samples(load_dataset(files["physics"]["path"]), info["split"]["train"],
                           count=plan.analysis_points * 10)
    seeds = []
    for i, run in enumerate(runs):
        where = folder if i == 0 else folder / f"seed-{run.seed}"
        result = analyze(true, run.model, q, samples=samples)
        write_report(result, where, max_table_q=max(k, 3))
        seeds.append({"seed": run.seed, "summary": summary_numbers(result),
                      "analysis": str(where / "analysis.json")})
    return {"summary": seeds[0]["summary"], "paper_q": k, "points": len(q),
            "report": str(folder / "report.md"), "seeds": seeds}
