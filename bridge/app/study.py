"""What ``softpinn reproduce`` runs: a :class:`Study`, one of the registry's
(:mod:`.studies`). A study runs its stages into an output folder (a typed run result:
:class:`StudyRun`), then writes its report and ``results.json``; :func:`.runner.reproduce`
does the rest (the output record, the log's last line)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from softpinn.bridge.tasks.plan import ReproduceConfig
from softpinn.progress import ProgressFn


class StudyRun(Protocol):
    """A study's stages, finished: the output folder, the plan (None where the study's parts
    have plans of their own) and the run's time so far [s]."""

    @property
    def out(self) -> Path: ...

    @property
    def plan(self) -> Any: ...

    @property
    def seconds(self) -> float: ...


@dataclass(frozen=True)
class Written:
    """A study's report, written: its path and the run's time [s] as ``results.json`` gives
    it (the report's own time counted where the study counts it: its figures are drawn then)."""

    report: Path
    seconds: float


class Study(Protocol):
    """One kind of study of ``softpinn reproduce``: the paper's tasks (and a spec file of the
    user's), the paper's experiment, the open challenges."""

    def run(self, config: ReproduceConfig, out_dir: str | Path, *,
            log: Callable[[str], None], progress: ProgressFn | None,
            force: bool) -> StudyRun:
        """Claim ``out_dir`` (:mod:`bridge.base.outputs`) and run the study's stages there."""
        ...

    def write_report(self, run: Any, *, machine: str) -> Written:
        """Write ``report.md`` (and the figures it shows) of a finished run; ``machine``
        describes the computer in it."""
        ...

    def write_results(self, run: Any, *, seconds: float, machine: str) -> dict:
        """Write ``results.json``; returns the results :class:`.runner.ReproduceResult` holds."""
        ...
