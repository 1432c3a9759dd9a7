"""The studies ``softpinn reproduce TASK`` runs (:class:`.study.Study`), and the registry that
picks one by TASK: a paper task (or a spec file of the user's) runs
:mod:`bridge.tasks.pipeline`, ``experiment`` :mod:`bridge.tasks.experiment`, ``challenges``
:mod:`bridge.challenges.pipeline`, ``cosserat`` :mod:`bridge.cosserat`; each writes its report
with :mod:`bridge.report`."""

from __future__ import annotations

import time
from collections.abc import Mapping
from types import MappingProxyType

from softpinn.bridge.app.study import Study, Written
from softpinn.bridge.challenges.pipeline import (
    ChallengesRun,
    results_document,
    run_challenges,
    write_strict_json,
)
from softpinn.bridge.cosserat import CosseratRun, run_cosserat
from softpinn.bridge.report.challenges import write_challenges_report
from softpinn.bridge.report.cosserat import write_cosserat_report
from softpinn.bridge.report.experiment import write_experiment_report
from softpinn.bridge.report.task import write_task_report
from softpinn.bridge.tasks.experiment import ExperimentRun, run_experiment
from softpinn.bridge.tasks.pipeline import TaskRun, draw_figures, run_task
from softpinn.bridge.tasks.plan import CHALLENGES, COSSERAT, EXPERIMENTS, TASKS
from softpinn.bridge.tasks.stages import write_json


class TaskStudy:
    """A paper task, or a spec file of the user's (:func:`bridge.tasks.pipeline.run_task`)."""

    def run(self, config, out_dir, *, log, progress, force) -> TaskRun:
        return run_task(config, out_dir, log=log, progress=progress, force=force)

    def write_report(self, run: TaskRun, *, machine: str) -> Written:
        t_report = time.perf_counter()
        figures = draw_figures(run)
        report = write_task_report(run.spec, run.plan, run.results, run.out,
                                   seconds=run.seconds, machine=machine, jobs=run.config.jobs,
                                   figures=figures)
        # the report's figures are part of the run
        return Written(report, run.seconds + time.perf_counter() - t_report)

    def write_results(self, run: TaskRun, *, seconds: float, machine: str) -> dict:
        write_json(run.out / "results.json", {
            "task": run.plan.task, "quick": run.plan.quick, "seconds": seconds,
            "jobs": run.config.jobs, "machine": machine, "results": run.results,
        })
        return run.results


class ExperimentStudy:
    """The paper's experiment with a simulated stand-in (:mod:`bridge.tasks.experiment`)."""

    def run(self, config, out_dir, *, log, progress, force) -> ExperimentRun:
        return run_experiment(config, out_dir, log=log, progress=progress, force=force)

    def write_report(self, run: ExperimentRun, *, machine: str) -> Written:
        t_report = time.perf_counter()
        report = write_experiment_report(run.spec, run.plan, run.results, run.out,
                                         seconds=run.seconds, machine=machine,
                                         jobs=run.config.jobs)
        # the report's figures are part of the run
        return Written(report, run.seconds + time.perf_counter() - t_report)

    def write_results(self, run: ExperimentRun, *, seconds: float, machine: str) -> dict:
        write_json(run.out / "results.json", {"task": "experiment", "quick": run.plan.quick,
                                              "seconds": seconds, "jobs": run.config.jobs,
                                              "machine": machine, "results": run.results})
        return run.results


class ChallengesStudy:
    """The paper's open challenges, each a study of its own (:mod:`bridge.challenges`)."""

    def run(self, config, out_dir, *, log, progress, force) -> ChallengesRun:
        return run_challenges(config, out_dir, log=log, progress=progress, force=force)

    def write_report(self, run: ChallengesRun, *, machine: str) -> Written:
        report = write_challenges_report(run.out, run.studies, quick=run.config.quick,
                                         seconds=run.seconds, machine=machine)
        return Written(report, run.seconds)  # the studies' time (they draw their figures)

    def write_results(self, run: ChallengesRun, *, seconds: float, machine: str) -> dict:
        results = results_document(run, seconds=seconds, machine=machine)
        write_strict_json(run.out / "results.json", results)
        return results


class CosseratStudy:
    """Networks against linear models on a Cosserat-rod stand-in arm (:mod:`bridge.cosserat`)."""

    def run(self, config, out_dir, *, log, progress, force) -> CosseratRun:
        return run_cosserat(config, out_dir, log=log, progress=progress, force=force)

    def write_report(self, run: CosseratRun, *, machine: str) -> Written:
        return Written(write_cosserat_report(run, seconds=run.seconds, machine=machine),
                       run.seconds)

    def write_results(self, run: CosseratRun, *, seconds: float, machine: str) -> dict:
        results = {"task": "cosserat", "quick": run.plan.quick, "seconds": seconds,
                   "machine": machine, "stage_seconds": run.stage_seconds,
                   "plan": run.plan.to_dict(), "results": run.results}
        write_strict_json(run.out / "results.json", results)
        return results


#: TASK -> the study that runs it; a TASK not here (a spec file) is a task's (:data:`TASK`)
TASK: Study = TaskStudy()
REGISTRY: Mapping[str, Study] = MappingProxyType({
    **{task: TASK for task in TASKS},
    **{task: ExperimentStudy() for task in EXPERIMENTS},
    **{task: ChallengesStudy() for task in CHALLENGES},
    **{task: CosseratStudy() for task in COSSERAT},
})


def study_for(task: str) -> Study:
    """The study that runs ``reproduce``'s TASK (a valid one: :class:`.ReproduceConfig`)."""
    return REGISTRY.get(task, TASK)
