"""``softpinn reproduce``'s library face: :func:`reproduce` runs a TASK's study (picked from
the registry, :mod:`.studies`) into an output folder and writes its report, ``results.json``
and the folder's record of what it wrote (:mod:`bridge.base.outputs`)."""

from __future__ import annotations

import os
import platform
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import jax

from softpinn.bridge.app.studies import study_for
from softpinn.bridge.base import outputs
from softpinn.bridge.figures.figsave import draft_figures
from softpinn.bridge.tasks.plan import Plan, ReproduceConfig
from softpinn.progress import ProgressFn


@dataclass(frozen=True)
class ReproduceResult:
    """What :func:`reproduce` returns: paths and every figure it measured."""

    config: ReproduceConfig
    out_dir: Path
    report: Path
    plan: Plan | None  # None for the challenges (studies with plans of their own)
    results: dict = field(repr=False)
    seconds: float = 0.0


def reproduce(
    config: ReproduceConfig | str,
    out_dir: str | Path,
    *,
    log: Callable[[str], None] | None = None,
    progress: ProgressFn | None = None,
    force: bool = False,
) -> ReproduceResult:
    """Run a paper task (or the experiment, the challenges, a spec file of the user's) end to
    end into ``out_dir`` (:mod:`bridge.tasks.pipeline`). ``out_dir`` may be new, empty or an
    earlier reproduce's (finished stages are reused); another non-empty folder is refused
    unless ``force`` (:mod:`bridge.base.outputs`: nothing of the user's is overwritten or
    removed). A quick run's figures are drafts (:mod:`bridge.figures.figsave`)."""
    if isinstance(config, str):
        config = ReproduceConfig(task=config)

    with draft_figures(config.quick):  # a quick run's figures are drafts (no print copies)
        jax.config.update("jax_enable_x64", True)
        log = log or (lambda s: None)
        machine = machine_description()
        study = study_for(config.task)
        run = study.run(config, out_dir, log=log, progress=progress, force=force)
        written = study.write_report(run, machine=machine)
        results = study.write_results(run, seconds=written.seconds, machine=machine)
        outputs.record(run.out, outputs.written_files(run.out))
        log(f"report: {written.report}")
        return ReproduceResult(config, run.out, written.report, run.plan, results,
                               written.seconds)


def notebook_run(task: str) -> tuple[ReproduceConfig, Path]:
    """The configuration and output folder a task notebook uses, from the environment:
    ``SOFTPINN_QUICK`` ("0" for the full run; default quick), ``SOFTPINN_OUT`` (default
    ``runs/notebooks``), and ``SOFTPINN_EPOCHS`` / ``SOFTPINN_LBFGS`` to override the budgets
    (the test suite runs the notebooks on the shortest budgets)."""
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
    """The computer a run's report names: architecture, cores, system, Python."""
    return f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}, " \
           f"Python {platform.python_version()}"
