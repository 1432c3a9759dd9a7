"""The paper's five tasks end to end: ``softpinn reproduce TASK``.

One call runs the whole study of a task (Section III-B, Section IV, Appendix B):

1. **data**: simulate the preset's trajectories with the paper's settings (``[data]``), split
   them as the paper does (physics-model training, black-box training, test);
2. **train**: the physics model(s) of the task (Task 1, 2: Lagrangian; Task 3: Hamiltonian;
   Task 4: Lagrangian and Hamiltonian; Task 5: Lagrangian on the fixed-step and on the 50, 100,
   1000 Hz data) and the black-box baseline, which gets more data as in the paper;
3. **predict**: one-step test error and rollouts over the paper's horizon (2.7 s, 5 s, 10 s),
   long rollouts (Fig. 9) and rollouts with another step size (Figs. 24-25); beside them, once
   per data set, the **baselines** every network must beat (no motion and least-squares linear
   models, :mod:`bridge.analysis.baselines`) at the same horizons;
4. **analyze**: learned against true M, M^-1, D, G, A at the paper's table q and at q sampled
   in the data's range, with the transforms of :mod:`bridge.transforms`;
5. **report**: ``report.md`` with Table III's row for the task beside ours, the matrix
   summaries and the figures (each data set's figures a stage of their own, ``draw/<variant>``:
   with ``--jobs`` drawn by a free worker as soon as that data set's models are done).

:func:`run_task` runs steps 1-4 and :func:`draw_figures` the figure stages; the report itself
(:mod:`bridge.report.task`) and ``results.json`` are written by ``softpinn.bridge.app``'s
``reproduce``, which dispatches a task to this pipeline.

Every stage writes its results under ``OUT/<stage>/`` and a ``done.json`` holding the settings
that made them; a second call with the same settings skips finished stages, so an interrupted
run loses at most the stage it was in (training itself resumes from its last checkpoint).

The same pipeline runs a spec file of the user's (``reproduce("my-arm.toml")``): its ``[data]``
table or the defaults from its physics, its ``[training]`` recipe or the recipe's defaults; the
report then gives our errors in Table III's columns, with no paper rows.

``quick=True`` runs the same pipeline on small settings (few short trajectories, small nets,
few epochs) in a minute or two; tests and notebooks use it. Full runs use the paper's network
sizes and data, with our own, shorter training budgets (the recipe's ``[training.full.*]``
tables, :mod:`symbolic.spec._recipe`).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softpinn import locks
from softpinn.bridge.base import outputs
from softpinn.bridge.figures.figsave import is_draft
from softpinn.bridge.figures.task import _variant_figures
from softpinn.bridge.tasks import parallel
from softpinn.bridge.tasks.measure_stages import (
    baselines_settings,
    stage_analyze,
    stage_baselines,
    stage_floor,
    stage_modes,
    stage_predict,
)
from softpinn.bridge.tasks.plan import Plan, ReproduceConfig, make_plan, task_spec
from softpinn.bridge.tasks.stages import (
    Stages,
    stage_data,
    stage_train,
    variant_model,
    write_json,
)
from softpinn.progress import ProgressFn


@dataclass(frozen=True)
class TaskRun:
    """A task run's stages, finished (:func:`run_task`): its spec and plan, the output folder and
    the stages' runner (the report's figure stages run on it), every result, and the run's time
    so far [s] (this call's, plus what the stages it reused took when they ran)."""

    config: ReproduceConfig
    spec: Any
    plan: Plan
    out: Path
    stages: Stages = field(repr=False)
    results: dict = field(repr=False)
    seconds: float


@locks.scope()  # the output's lock is given up when the call returns
def run_task(config: ReproduceConfig, out_dir, *, log: Callable[[str], None],
             progress: ProgressFn | None = None, force: bool = False) -> TaskRun:
    """Run a task's stages into ``out_dir`` (see the module docstring): the data, then every
    model's train, predict, floor, modes and analyze stages (with ``config.jobs`` > 1 in worker
    processes first). Writes ``plan.json`` and the stages' folders; the figures, the report and
    ``results.json`` are the caller's (:func:`draw_figures`, :mod:`bridge.report.task`)."""
    spec = task_spec(config.task, log)  # a bad spec file is refused before --out is made
    out = outputs.claim(out_dir, "reproduce", force=force)
    t_start = time.perf_counter()
    plan = make_plan(spec, config)
    write_json(out / "plan.json", plan.to_dict())
    stages = Stages(out, log)

    data_settings = _data_settings(plan, spec)
    data = stages.run("data", data_settings, lambda d: stage_data(spec, plan, d))
    results: dict[str, Any] = {"data": data, "variants": {}}
    if config.jobs > 1:  # every model's stages in worker processes, then gathered below
        work = _unfinished_models(config, out, plan, data, spec)
        after = _unfinished_figures(config, out, plan, data, spec, {w[0] for w in work})
        by_workers = parallel.run_models(work, jobs=config.jobs, log=log, progress=progress,
                                         after=after)
        stages.ran |= by_workers
        stages.quiet |= by_workers
    elif not plan.quick:
        parallel.suggest_jobs(len(_unfinished_models(config, out, plan, data, spec)), log)
    credit: dict[str, float] = {}  # training time of runs resumed when already finished
    for variant in plan.variants:
        vres: dict[str, Any] = {"models": {}}
        for kind in variant.models:
            entry, credit_s = model_stages(spec, plan, stages, variant, kind, data,
                                           data_settings, progress)
            credit[f"train/{variant.name}/{kind}"] = credit_s
            vres["models"][kind] = entry
            pr = entry["predict"]
            log(f"{variant.name}/{kind}: test {pr['test_error']['mean']:.3e}, rollout "
                f"{pr['prediction_error']['mean']:.3e} over {plan.horizon:g} s")
        files = data["variants"][variant.name]
        vres["baselines"] = stages.run(f"baselines/{variant.name}",
                                       baselines_settings(plan, files, data_settings),
                                       lambda d, f=files: stage_baselines(plan, f))
        first = vres["baselines"]["horizons"][0]
        log(f"{variant.name}/baselines: " + ", ".join(
            f"{s['name']} {'diverged' if s['mean'] is None else format(s['mean'], '.3e')}"
            for s in vres["baselines"]["scores"] if s["horizon"] == first)
            + f" over {first:g} s")
        results["variants"][variant.name] = vres
    # the run's time: this call's wall time, plus what the stages it reused from earlier calls
    # took when they ran (stages run here, by this process or its workers, are in the wall time)
    seconds = sum(stages.seconds.values()) + sum(credit.values()) + (
        time.perf_counter() - t_start - sum(
            v for k, v in stages.seconds.items() if k in stages.ran))
    results["stage_seconds"] = {k: v + credit.get(k, 0.0) for k, v in stages.seconds.items()}
    return TaskRun(config, spec, plan, out, stages, results, seconds)


def draw_figures(run: TaskRun) -> dict[str, list[str]]:
    """Every data set's figure stage (:func:`figure_stage`, ``draw/<variant>``) of a finished
    run: the report lines that show each data set's figures, by variant."""
    plan = run.plan
    return {v.name: figure_stage(run.spec, plan, run.stages, v.name,
                                 run.results["variants"][v.name]["models"], i == 0)
            for i, v in enumerate(plan.variants)}


def model_stages(spec, plan: Plan, stages: Stages, variant, kind: str, data: dict,
                 data_settings: dict, progress) -> tuple[dict, float]:
    """Train, predict, floor, modes and (physics models) analyze one model of a variant, each
    a resumable stage; returns the model's results and the training time of a run found
    finished (a reused run takes no time now: the report counts the time it trained)."""
    files = data["variants"][variant.name]
    mplan = variant_model(plan, variant, kind, files)
    # the data settings too: a data set simulated again under the same file name must not
    # leave models trained on the old one
    settings = {"model": mplan.to_dict(), "files": files, "data": data_settings,
                "batch": plan.batch_size, "seeds": plan.seeds, "float32": plan.float32,
                "samples": plan.physics_samples if kind != "blackbox" else None}
    name = f"train/{variant.name}/{kind}"
    tr = stages.run(name, settings,
                    lambda d: stage_train(spec, plan, kind, mplan, files, d, progress))
    trained = sum(float(m.get("seconds", 0.0)) for m in tr["metrics"].get("members", []))
    credit = max(0.0, trained - stages.seconds[name])
    pr = stages.run(f"predict/{variant.name}/{kind}",
                    {"train": settings, "horizon": plan.horizon,
                     "long": plan.long_horizon, "dt": plan.other_dt},
                    lambda d: stage_predict(plan, kind, files, tr, d))
    fl = stages.run(f"floor/{variant.name}/{kind}",
                    {"files": files, "data": data_settings, "no_forces": True,
                     "integration": mplan.integration(),
                     "state": "momentum" if kind == "hamiltonian" else "velocity"},
                    lambda d: stage_floor(spec, kind, mplan, files))
    mo = stages.run(f"modes/{variant.name}/{kind}", {"train": settings},
                    lambda d: stage_modes(spec, kind, files, tr))
    entry = {"train": tr, "predict": pr, "floor": fl, "modes": mo}
    if kind != "blackbox":
        entry["analyze"] = stages.run(
            f"analyze/{variant.name}/{kind}",
            {"train": settings, "points": plan.analysis_points, "every_seed": True,
             "force_samples": plan.analysis_points * 10, "accelerations": 3},
            lambda d: stage_analyze(spec, plan, tr, files, d),
        )
    return entry, credit


def figure_stage(spec, plan: Plan, stages: Stages, vname: str, models: dict,
                 first: bool) -> list[str]:
    """Stage ``draw/<variant>``: the report's figures of one data set (loss curves, rollouts,
    the arm; the first data set's animation too) from its models' results; returns the report
    lines that show them. Drawn again when a figure it drew is gone."""
    name = f"draw/{vname}"
    settings = {"models": models, "draft": is_draft(), "animate": first}
    stored = stages.finished(name, settings)
    if stored is not None:
        lines = stored["result"]["lines"]
        drawn = re.findall(r"\]\(([^)\s]+)\)", "\n".join(lines))
        if not all((stages.out / p).is_file() for p in drawn):
            (stages.out / name / "done.json").unlink()
    fig_dir = stages.out / "figures"
    return stages.run(name, settings, lambda d: {"lines": _variant_figures(
        spec, plan, vname, models, fig_dir, stages.out, first)})["lines"]


def _unfinished_figures(config: ReproduceConfig, out: Path, plan: Plan, data: dict, spec,
                        training: set[str]) -> list:
    """The ``after`` work of :func:`.parallel.run_models`: ``[(key, needs, function, args)]``
    of every data set whose figures are not drawn yet (needs: its models still to run)."""
    settings = _data_settings(plan, spec)
    work = []
    for i, variant in enumerate(plan.variants):
        needs = [f"{variant.name}/{kind}" for kind in variant.models]
        if not set(needs) & training:  # its models are finished: are its figures drawn?
            probe = parallel.Probe(out, lambda _: None)
            models = {k: model_stages(spec, plan, probe, variant, k, data, settings, None)[0]
                      for k in variant.models}
            try:
                figure_stage(spec, plan, probe, variant.name, models, i == 0)
                continue
            except parallel.NotDone:
                pass
        work.append((f"draw/{variant.name}", needs, _figures_worker,
                     (config, str(out), variant.name)))
    return work


def _figures_worker(config: ReproduceConfig, out: str, variant_name: str) -> list[str]:
    """One data set's report figures in a ``--jobs`` worker, once its models are done."""
    spec = task_spec(config.task)
    plan = make_plan(spec, config)
    settings = _data_settings(plan, spec)
    probe = parallel.Probe(Path(out), lambda _: None)
    data = probe.run("data", settings, None)
    first = plan.variants[0].name == variant_name
    variant = next(v for v in plan.variants if v.name == variant_name)

    def body(stages, progress):
        models = {k: model_stages(spec, plan, probe, variant, k, data, settings, None)[0]
                  for k in variant.models}
        figure_stage(spec, plan, stages, variant_name, models, first)

    return parallel.run_in_worker(config, f"draw/{variant_name}", out, body)


def _data_settings(plan: Plan, spec) -> dict:
    """The data stage's settings (its record's key, and so every later stage's). A spec file of
    the user's adds its physics: edited, it makes new data and new models (a preset's physics
    is the package's)."""
    settings = {"plan_data": plan.data, "fixed": plan.fixed_step}
    if not spec.source.startswith("preset:"):
        settings["physics"] = spec.physics_dict()
    return settings


def _unfinished_models(config: ReproduceConfig, out: Path, plan: Plan, data: dict, spec) -> list:
    """The work of :func:`.parallel.run_models`: ``[(key, function, args, epochs)]`` of every
    model whose chain of stages has not finished."""
    settings = _data_settings(plan, spec)
    work = []
    for variant in plan.variants:
        for kind in variant.models:
            def chain(stages, v=variant, k=kind):
                return model_stages(spec, plan, stages, v, k, data, settings, None)

            if parallel.unfinished(chain, out):
                m = variant_model(plan, variant, kind, data["variants"][variant.name])
                work.append((f"{variant.name}/{kind}", _model_worker,
                             (config, str(out), variant.name, kind), int(m.epochs)))
    return work


def _model_worker(config: ReproduceConfig, out: str, variant_name: str, kind: str) -> list[str]:
    """One model's stages in a ``--jobs`` worker (:mod:`.parallel`); returns the stages it ran."""
    spec = task_spec(config.task)
    plan = make_plan(spec, config)
    settings = _data_settings(plan, spec)
    data = parallel.Probe(Path(out), lambda _: None).run("data", settings, None)
    variant = next(v for v in plan.variants if v.name == variant_name)
    return parallel.run_in_worker(config, f"{variant_name}/{kind}", out, lambda stages, progress: (
        model_stages(spec, plan, stages, variant, kind, data, settings, progress)))
