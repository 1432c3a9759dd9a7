"""``softpinn reproduce challenges``: the paper's three open challenges (Section VI-B) run as
studies into one folder, with one report (:mod:`bridge.report.challenges`).

    OUT/
      report.md           the verdict, a table of every target met or missed, then each study
      results.json        every number, the settings (quick or not) and the machine
      <study>/            what each study wrote (runs, figures, study.json)

A study that finished in an earlier call with the same settings (``<study>/study.json``) is
reused, not run again; an interrupted study starts over in its own folder (its own stages may
resume). Nothing of the user's is overwritten (:mod:`bridge.base.outputs`).
"""

from __future__ import annotations

import importlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softpinn import locks
from softpinn.bridge.base import outputs
from softpinn.bridge.tasks.plan import ReproduceConfig
from softpinn.files import write_json

#: The studies, in the report's order: module of :mod:`bridge.challenges` and its challenge.
STUDIES = (
    ("fast", "1. Fast Lagrangian training"),
    ("known", "2a. The ideal Lagrangian solution: a known actuator model"),
    ("labels", "2b. The ideal Lagrangian solution: additional labels"),
    ("velocity", "3. Hamiltonian networks from velocity data"),
)


@dataclass(frozen=True)
class ChallengesRun:
    """The studies of :data:`STUDIES`, run (:func:`run_challenges`): the output folder, each
    study's ``{"title", "markdown", "results", "seconds"}`` by name, and the wall time [s]."""

    config: ReproduceConfig
    out: Path
    studies: dict[str, dict[str, Any]] = field(repr=False)
    seconds: float
    plan: None = None  # the studies have plans of their own


def run_study(name: str, out: Path, *, quick: bool, log: Callable[[str], None],
              progress=None) -> dict[str, Any]:
    """One study into ``out / name``, or its earlier finished result with the same settings."""
    folder = out / name
    done = folder / "study.json"
    settings = {"quick": bool(quick)}
    if done.is_file():
        try:
            stored = json.loads(done.read_text())
        except (OSError, ValueError):
            stored = None
        if isinstance(stored, dict) and stored.get("settings") == settings:
            log(f"{name}: finished earlier, reused")
            return stored["study"]
    folder.mkdir(parents=True, exist_ok=True)
    # the study modules are looked up by name (a test puts stand-ins in their place)
    module = importlib.import_module(f"{__package__}.{name}")
    t0 = time.perf_counter()
    study = module.run_study(folder, quick=quick, log=log, progress=progress)
    study.setdefault("seconds", time.perf_counter() - t0)
    write_strict_json(done, {"settings": settings, "study": study})
    return study


def write_strict_json(path: Path, obj: Any) -> None:
    """``obj`` as strict JSON into ``path``, written whole, non-finite numbers as null
    (:func:`softpinn.files.write_json`): ``study.json`` and the challenges' ``results.json``."""
    write_json(path, obj, indent=1, end="", default=_jsonable)


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON-ready: {type(x).__name__}")


@locks.scope()  # the output's lock is given up when the call returns
def run_challenges(config: ReproduceConfig, out_dir, *, log: Callable[[str], None],
                   progress=None, force: bool = False) -> ChallengesRun:
    """Run every study of :data:`STUDIES` into ``out_dir`` (``config.quick``: their quick
    forms). The report (:mod:`bridge.report.challenges`) and ``results.json``
    (:func:`results_document`) are the caller's (``softpinn.bridge.app``'s ``reproduce``)."""
    quick = config.quick
    out = outputs.claim(out_dir, "reproduce", force=force)
    t0 = time.perf_counter()
    studies = {}
    for name, title in STUDIES:
        log(f"{title}: running" + (" (quick)" if quick else ""))
        studies[name] = run_study(name, out, quick=quick, log=log, progress=progress)
        log(f"{title}: {studies[name].get('seconds', 0.0):.0f} s")
    return ChallengesRun(config, out, studies, time.perf_counter() - t0)


def results_document(run: ChallengesRun, *, seconds: float, machine: str) -> dict[str, Any]:
    """What ``results.json`` holds: every study's results (not its report section), the
    settings and the machine."""
    return {"task": "challenges", "quick": run.config.quick, "seconds": seconds,
            "machine": machine,
            "studies": {n: {k: v for k, v in s.items() if k != "markdown"}
                        for n, s in run.studies.items()}}
