"""The paper's experiment with a simulated stand-in: ``softpinn reproduce experiment``.

Section V of the paper learned a one-segment tendon-driven arm from an IMU on its tip (Table IV,
Figs. 13-17 and 51-63); the recordings are not public. This pipeline builds the closest honest
stand-in from the ``experiment`` preset (``docs/experiment.md``) and runs the paper's study on it:

1. **data**: simulate the arm (the preset's physics and ``[data]``: four tendons given sinusoids,
   128 trajectories, the last 8 for test) at the highest rate of the study;
2. **record**: the preset's ``[sensor]`` (an IMU: tip orientation with white noise and a drifting
   bias, :mod:`symbolic.spec._sensor`) records every trajectory at each rate of the study (``[data]
   rates``; the sensor's own ``rate_hz`` is the paper's, 5 Hz) and writes the CSV files
   ``softpinn import`` reads;
3. **import**: each recording through ``softpinn import``'s library (orientation -> bending, the
   stretch unobservable and set to 0) with each preprocessing of :data:`PREPROCESSING` (none,
   moving average, piecewise polynomial fits, Savitzky-Golay), windows set in seconds;
4. **train**: a Lagrangian network and a black box on each data set, at the data's step (the
   paper's 0.2 s at 5 Hz), with RK4 sub-steps no longer than the recipe's ``max_step``;
5. **predict**: one-step train and test errors, the prediction over the recipe's horizon (5 s)
   without reset (Figs. 14, 16) and over the whole test trajectory with the state reset from the
   processed measurement every :data:`RESET_EVERY` seconds (Figs. 15, 17), each against the
   processed measurement (what the paper could score) and against the true arm (what only a
   simulation knows); beside them, on each data set, the **baselines** every network must beat
   (no motion and linear models on the same bending coordinates,
   :mod:`bridge.analysis.baselines`), scored against the processed measurement the same ways;
6. **bending**: the Lagrangian network's M, D, G, A in the observable bending block (dx, dy at
   dL = 0) against the true ones, through the transforms of :mod:`bridge.analysis`;
7. **report**: ``report.md`` with the Table IV analogue beside the paper's figures, the rate x
   preprocessing table, the matrices, and the figures (:mod:`bridge.report.experiment`, written
   by ``softpinn.bridge.app``'s ``reproduce`` after :func:`run_experiment` ran steps 1-6).

With ``--actuator TAU:DELAY`` (``ReproduceConfig.actuator``, issue 43) the tendons follow their
commands through a first-order lag and a dead time (:mod:`softpinn.actuator`): the spec gets the
``[actuator]`` table, so the arm is simulated behind it with the commands recorded as u, the
import writes ``meta["actuator"]``, and the networks (``TrainConfig.actuator``) and the baselines
are given the same actuator (known, not learned). Without it nothing differs from before.

Every step is a stage (:class:`.stages.Stages`): rerun with the same settings, finished stages are
skipped. ``quick`` shrinks the data, the rates, the networks and the budgets to run in a minute or
two.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softpinn import locks
from softpinn.actuator import Actuator
from softpinn.bridge.base import outputs
from softpinn.bridge.tasks import parallel
from softpinn.bridge.tasks.experiment_stages import (
    baselines_settings,
    rate_name,
    stage_baselines,
    stage_bending,
    stage_import,
    stage_predict,
    stage_record,
    stage_simulate,
    stage_train,
)
from softpinn.bridge.tasks.plan import MIN_WIDTH, ReproduceConfig, substeps_for
from softpinn.bridge.tasks.stages import Stages, write_json
from softpinn.errors import UserError
from softpinn.symbolic import LOSS_KEYS, MODEL_KEYS, data_config, load_spec, sensor_config

#: The state is reset from the processed measurement this often in the long predictions [s]
#: (the paper's Figs. 15, 17: "3 seconds state updating").
RESET_EVERY = 3.0

#: The preprocessings compared, as ``softpinn import --smooth`` texts made for each rate from
#: windows in seconds (at least ``min`` samples): the paper's moving average (MATLAB movmean)
#: and piecewise polynomial fits (polyfit), Savitzky-Golay, and none. Savitzky-Golay is of degree
#: 3: at a window's centre a fit of even degree 2k has the slope of degree 2k - 1, so quadratics
#: give the velocities of straight lines, which at 5 Hz (savgol:5:2, 1 s) lost 29 % of a 0.6 Hz
#: swing's velocity and were 0.120 rad/s rms off the true arm's (0.056 raw, 0.054 with cubics);
#: cubics over 0.8 s instead of quadratics over 0.4 s gave both networks lower 5 s errors at
#: every rate (RESULTS.md, 27 Nov 2026). ``differences``: the order of the central differences
#: (``softpinn import --differences``) where the smoother has no derivative of its own (2 where
#: not given). The raw data take fourth-order differences: second order keeps 91 % of a 0.6 Hz
#: swing's velocity at 5 Hz, fourth order 99 % (RESULTS.md, 27 Nov 2026).
PREPROCESSING: dict[str, dict[str, Any]] = {
    "none": {"differences": 4},
    "movmean": {"window_s": 0.2, "min": 3},
    "polyfit": {"degree": 3, "window_s": 1.0, "min": 5},
    "savgol": {"degree": 3, "window_s": 0.8, "min": 5},
}
#: Table IV's columns: which of ours stands beside which of the paper's
PAPER_COLUMNS = {"movmean": "smoothing", "polyfit": "polynomial_fitting"}
KINDS = ("lagrangian", "blackbox")
#: trajectories of a quick run (the last two for test)
QUICK_TRAJECTORIES, QUICK_TEST = 12, 2


def differences(name: str) -> int:
    """The order of the central differences of preprocessing ``name`` (``--differences``)."""
    return int(PREPROCESSING[name].get("differences", 2))


def smoother(name: str, rate: float) -> str:
    """The ``--smooth`` text of preprocessing ``name`` at ``rate`` Hz."""
    p = PREPROCESSING[name]
    if name == "none":
        return "none"
    w = max(int(p["min"]), int(round(p["window_s"] * rate)))
    if name == "movmean":
        return f"movmean:{w}"
    if name == "savgol":
        w += 1 - w % 2  # odd
        return f"savgol:{w}:{p['degree']}"
    return f"polyfit:{p['degree']}:{w}"


@dataclass(frozen=True)
class ExperimentPlan:
    """What an experiment run does (written to ``OUT/plan.json``)."""

    quick: bool
    data: Mapping[str, Any]
    sensor: Mapping[str, Any]
    main_rate: float
    rates: tuple[float, ...]
    sim_rate: float
    trajectories: int
    test_trajectories: int
    preprocessing: Mapping[str, Mapping[str, str]]  # rate name -> preprocessing -> smoother
    differences: Mapping[str, int]  # preprocessing -> order of its central differences
    substeps: Mapping[str, int]  # rate name -> RK4 sub-steps per data step
    models: Mapping[str, Mapping[str, Any]]
    samples: int | None
    batch_size: int
    input_hold: str
    horizon: float
    reset_every: float
    analysis_points: int
    seeds: int
    float32: bool
    #: the lag and dead time between the commands and the arm (``--actuator`` or the spec's
    #: ``[actuator]`` table): ``time_constant`` and ``delay`` [s], one value or one per input;
    #: None: the commands reach the arm at once (as before the option existed)
    actuator: Mapping[str, list[float]] | None = None
    #: the networks' linear prior (``--prior``, learn/_prior.py): none (the paper's networks,
    #: trained from scratch) or linear (they start as the least-squares linear model)
    prior: str = "none"

    def to_dict(self) -> dict[str, Any]:
        d = json.loads(json.dumps(dataclasses.asdict(self)))
        if self.actuator is None:
            d.pop("actuator")  # plan.json as before the option existed
        if self.prior == "none":
            d.pop("prior")
        return d

    def actuator_dynamics(self, m: int) -> Actuator:
        """The actuator the arm, the networks and the baselines share (identity without one)."""
        return Actuator.from_dict(self.actuator, m) if self.actuator else Actuator()


def plan_actuator(spec, config: ReproduceConfig) -> dict[str, list[float]] | None:
    """The run's actuator as a spec's ``[actuator]`` table: ``--actuator``, else the spec's own
    table; None where neither gives one (or it is the identity)."""
    if config.actuator is not None:
        try:
            act = Actuator.parse(config.actuator, spec.m)
        except UserError as e:  # (one per input: the spec's count of inputs)
            raise UserError(f"--actuator: {str(e).removeprefix('actuator: ')}") from None
    elif spec.actuator:
        act = Actuator.from_dict(spec.actuator, spec.m)
    else:
        return None
    if act.is_identity:
        return None
    return {"time_constant": list(act.time_constant), "delay": list(act.delay)}


def experiment_spec(spec, plan: ExperimentPlan):
    """The spec the run simulates and imports with: the preset's, with the plan's actuator as
    its ``[actuator]`` table (the arm integrated behind it, ``meta["actuator"]`` written)."""
    table = dict(plan.actuator) if plan.actuator else {}
    if dict(spec.actuator) == table:
        return spec
    return dataclasses.replace(spec, actuator=table)


def make_experiment_plan(spec, config: ReproduceConfig) -> ExperimentPlan:
    """The plan from the preset's ``[data]``, ``[sensor]`` and ``[training]`` tables."""

    sensor = sensor_config(spec)
    recipe = spec.recipe
    # the experiment trains on the imported bending (n = 2) with eq. 8 and learned matrices:
    # a recipe's loss or model settings would be silently ignored, so they are refused
    unused = [f"[training.{kind}] {key}" for kind in KINDS
              for key in recipe.networks.get(kind, {}) if key in LOSS_KEYS or key in MODEL_KEYS]
    if unused:
        raise UserError(f"{spec.name}: {unused[0]} is not used by `reproduce experiment` (its "
                        "networks learn the imported bending with eq. 8 and learned matrices); "
                        "remove it")
    cfg = data_config(spec)
    data = dict(spec.data)
    quick = config.quick
    total = cfg.total_trajectories()
    ntest = cfg.test_trajectories
    rates = sorted(set(cfg.rates) | {sensor.rate_hz})
    if quick:
        total, ntest = QUICK_TRAJECTORIES, QUICK_TEST
        data["duration"] = recipe.quick["duration"]
        rates = sorted(set(recipe.quick.get("rates", (sensor.rate_hz,))) | {sensor.rate_hz})
    data.pop("rates", None)
    data.pop("rate", None)
    data.update(trajectories=total, test_trajectories=ntest)
    data.pop("train_trajectories", None)
    data.pop("blackbox_train_trajectories", None)
    sim_rate = max(rates)
    max_step = recipe.max_step
    substeps = {rate_name(r): (substeps_for(1.0 / r, max_step) if max_step else
                               int(recipe.substeps)) for r in rates}
    models: dict[str, dict[str, Any]] = {}
    for kind in KINDS:
        budget = recipe.full.get(kind, {})
        if quick:
            m = dict(mass=(16, 2), potential=(16, 2), damping=(8, 2), input=(8, 2),
                     hidden=(32, 2), epochs=int(recipe.quick["epochs"]), lr=3e-3)
        else:
            m = dict(mass=recipe.network("lagrangian", "mass", (64, 3)),
                     potential=recipe.network("lagrangian", "potential", (64, 3)),
                     damping=recipe.network("lagrangian", "damping", (16, 2)),
                     input=recipe.network("lagrangian", "input", (16, 2)),
                     hidden=recipe.network("blackbox", "hidden", (128, 3)),
                     epochs=int(budget.get("epochs", 100)), lr=float(budget.get("lr", 2e-3)))
            for name in ("mass", "potential"):
                m[name] = (max(m[name][0], MIN_WIDTH), m[name][1])
        m["paper_epochs"] = recipe.network(kind, "epochs")
        if config.epochs is not None:
            m["epochs"] = config.epochs
        models[kind] = m
    return ExperimentPlan(
        quick=quick, data=data, sensor=sensor.to_dict(), main_rate=sensor.rate_hz,
        rates=tuple(rates), sim_rate=sim_rate, trajectories=total, test_trajectories=ntest,
        preprocessing={rate_name(r): {p: smoother(p, r) for p in PREPROCESSING} for r in rates},
        differences={p: differences(p) for p in PREPROCESSING},
        substeps=substeps, models=models,
        samples=None if quick else cfg.physics_samples, batch_size=recipe.batch_size,
        input_hold=recipe.input_hold, horizon=float(recipe.prediction_horizon),
        reset_every=RESET_EVERY, analysis_points=config.analysis_points or (30 if quick else 200),
        seeds=config.seeds, float32=config.float32, actuator=plan_actuator(spec, config),
        prior="linear" if config.prior in ("linear", "auto") else "none",
    )


# ---------------------------------------------------------------------------------- pipeline


@dataclass(frozen=True)
class ExperimentRun:
    """The experiment's stages, finished (:func:`run_experiment`): its spec and plan, the output
    folder, every result and the run's time so far [s]."""

    config: ReproduceConfig
    spec: Any
    plan: ExperimentPlan
    out: Path
    results: dict = field(repr=False)
    seconds: float


@locks.scope()  # the output's lock is given up when the call returns
def run_experiment(config: ReproduceConfig, out_dir, *, log: Callable[[str], None],
                   progress=None, force: bool = False) -> ExperimentRun:
    """Run the experiment's stages into ``out_dir`` (see the module docstring, steps 1-6). The
    report (:mod:`bridge.report.experiment`) and ``results.json`` are the caller's
    (``softpinn.bridge.app``'s ``reproduce``)."""
    out = outputs.claim(out_dir, "reproduce", force=force)
    t_start = time.perf_counter()
    spec = load_spec(config.task)
    plan = make_experiment_plan(spec, config)
    spec = experiment_spec(spec, plan)
    write_json(out / "plan.json", plan.to_dict())
    stages = Stages(out, log)
    if plan.actuator:
        log(f"actuator: {plan.actuator_dynamics(spec.m).describe()}, known to the models")
    sim = stages.run("data", _with_actuator(plan, {"data": plan.data, "rate": plan.sim_rate}),
                     lambda d: stage_simulate(spec, plan, d))
    results: dict[str, Any] = {"data": sim, "rates": {}}
    if plan.actuator:  # (none: results.json as before the option existed)
        act = plan.actuator_dynamics(spec.m)
        results["actuator"] = {"text": act.text(), "describe": act.describe(),
                               **spec.actuator_meta()}
    imports = {}  # (rate, preprocessing) -> the import stage's result and settings
    for rate in plan.rates:
        rn = rate_name(rate)
        rec = stages.run(f"record/{rn}", _record_settings(plan, rate),
                         lambda d, r=rate: stage_record(spec, plan, r, sim, d))
        results["rates"][rn] = {"record": rec, "preprocessing": {}}
        for prep, smooth in plan.preprocessing[rn].items():
            imp_settings = _import_settings(plan, rec, smooth, prep)
            imp = stages.run(f"import/{rn}/{prep}", imp_settings,
                             lambda d, s=smooth, r=rec, o=plan.differences[prep]: stage_import(
                                 spec, plan, r, s, d, differences=o))
            imports[rate, prep] = (rec, imp, imp_settings)
    # the models not trained and analysed yet: with --jobs, in worker processes first
    work = [(f"{rate_name(rate)}/{prep}/{kind}", _model_worker,
             (config, str(out), rate, prep, kind), int(plan.models[kind]["epochs"]))
            for (rate, prep), made in imports.items() for kind in KINDS
            if parallel.unfinished(lambda st, r=rate, p=prep, k=kind, m=made: model_stages(
                spec, plan, st, r, p, k, *m, None), out)]
    if config.jobs > 1:
        by_workers = parallel.run_models(work, jobs=config.jobs, log=log, progress=progress)
        stages.ran |= by_workers
        stages.quiet |= by_workers
    elif not plan.quick:
        parallel.suggest_jobs(len(work), log)
    for (rate, prep), made in imports.items():
        rn = rate_name(rate)
        entry: dict[str, Any] = {"import": made[1], "models": {}}
        for kind in KINDS:
            model = model_stages(spec, plan, stages, rate, prep, kind, *made, progress)
            entry["models"][kind] = model
            e = model["predict"]["prediction_error_truth"]
            log(f"{rn}/{prep}/{kind}: prediction error against the true arm "
                f"{_fmt(e['mean'])} over {model['predict']['prediction_error']['horizon_s']:g} s")
        entry["baselines"] = stages.run(f"baselines/{rn}/{prep}",
                                        baselines_settings(plan, made[2]),
                                        lambda d, i=made[1]: stage_baselines(plan, i))
        results["rates"][rn]["preprocessing"][prep] = entry
    seconds = sum(stages.seconds.values()) + (
        time.perf_counter() - t_start - sum(v for k, v in stages.seconds.items()
                                            if k in stages.ran))
    results["stage_seconds"] = dict(stages.seconds)
    return ExperimentRun(config, spec, plan, out, results, seconds)


def _with_actuator(plan: ExperimentPlan, settings: dict) -> dict:
    """A stage's settings with the run's actuator (none: as before the option existed), so that
    a run with another actuator redoes the stage; the later stages' settings hold the import's."""
    return {**settings, "actuator": dict(plan.actuator)} if plan.actuator else settings


def _record_settings(plan: ExperimentPlan, rate: float) -> dict:
    return _with_actuator(plan, {"data": plan.data, "sensor": plan.sensor, "rate": rate})


def _import_settings(plan: ExperimentPlan, rec: dict, smooth: str, prep: str) -> dict:
    out = {"record": rec["csv"], "sensor": rec["sensor"], "data": plan.data, "smooth": smooth,
           "test": plan.test_trajectories}
    if plan.differences[prep] != 2:  # (the settings of second order as before it was a choice)
        out["differences"] = plan.differences[prep]
    return _with_actuator(plan, out)


def model_stages(spec, plan: ExperimentPlan, stages: Stages, rate: float, prep: str, kind: str,
                 rec: dict, imp: dict, imp_settings: dict, progress) -> dict:
    """Train, predict and (the Lagrangian network) the bending matrices of one model on one
    recording rate and preprocessing, each a resumable stage."""
    rn = rate_name(rate)
    settings = {"import": imp_settings, "model": plan.models[kind],
                "samples": plan.samples, "batch": plan.batch_size,
                "substeps": plan.substeps[rn], "hold": plan.input_hold,
                "seeds": plan.seeds, "float32": plan.float32,
                **({"prior": plan.prior} if plan.prior != "none" else {})}
    tr = stages.run(f"train/{rn}/{prep}/{kind}", settings,
                    lambda d: stage_train(spec, plan, kind, rate, imp, d, progress))
    pr = stages.run(f"predict/{rn}/{prep}/{kind}",
                    {"train": settings, "horizon": plan.horizon,
                     "reset_every": plan.reset_every},
                    lambda d: stage_predict(plan, kind, rate, imp, rec, tr, d))
    model = {"train": tr, "predict": pr}
    if kind == "lagrangian":
        model["bending"] = stages.run(
            f"bending/{rn}/{prep}", {"train": settings, "points": plan.analysis_points},
            lambda d: stage_bending(spec, plan, imp, tr))
    return model


def _model_worker(config: ReproduceConfig, out: str, rate: float, prep: str,
                  kind: str) -> list[str]:
    """One model's stages in a ``--jobs`` worker (:mod:`.parallel`); returns the stages it ran."""

    spec = load_spec(config.task)
    plan = make_experiment_plan(spec, config)
    spec = experiment_spec(spec, plan)
    rn = rate_name(rate)
    probe = parallel.Probe(Path(out), lambda _: None)
    rec = probe.run(f"record/{rn}", _record_settings(plan, rate), None)
    imp_settings = _import_settings(plan, rec, plan.preprocessing[rn][prep], prep)
    imp = probe.run(f"import/{rn}/{prep}", imp_settings, None)
    return parallel.run_in_worker(config, f"{rn}/{prep}/{kind}", out, lambda stages, progress: (
        model_stages(spec, plan, stages, rate, prep, kind, rec, imp, imp_settings, progress)))


def _fmt(x) -> str:
    return "diverged" if x is None else f"{x:.3g}"
