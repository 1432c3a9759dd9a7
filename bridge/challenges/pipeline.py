"""``softpinn reproduce challenges``: the paper's three open challenges (Section VI-B) run as
studies into one folder, with one report.

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
from pathlib import Path
from typing import Any

from softpinn.bridge.base import outputs

#: The studies, in the report's order: module of :mod:`bridge.challenges` and its challenge.
STUDIES = (
    ("fast", "1. Fast Lagrangian training"),
    ("known", "2a. The ideal Lagrangian solution: a known actuator model"),
    ("labels", "2b. The ideal Lagrangian solution: additional labels"),
    ("velocity", "3. Hamiltonian networks from velocity data"),
)


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
    module = importlib.import_module(f"{__package__}.{name}")
    t0 = time.perf_counter()
    study = module.run_study(folder, quick=quick, log=log, progress=progress)
    study.setdefault("seconds", time.perf_counter() - t0)
    tmp = done.with_name(done.name + ".tmp")
    tmp.write_text(json.dumps({"settings": settings, "study": study}, indent=1,
                              allow_nan=False, default=_jsonable))
    tmp.replace(done)
    return study


def _jsonable(x):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON-ready: {type(x).__name__}")


def run_challenges(out_dir, *, quick: bool, log: Callable[[str], None] | None = None,
                   progress=None, force: bool = False, machine: str = ""):
    """Run every study of :data:`STUDIES` into ``out_dir`` and write the report; returns
    ``(out, report, results, seconds)``."""
    log = log or (lambda s: None)
    out = outputs.claim(out_dir, "reproduce", force=force)
    t0 = time.perf_counter()
    studies = {}
    for name, title in STUDIES:
        log(f"{title}: running" + (" (quick)" if quick else ""))
        studies[name] = run_study(name, out, quick=quick, log=log, progress=progress)
        log(f"{title}: {studies[name].get('seconds', 0.0):.0f} s")
    seconds = time.perf_counter() - t0
    report = write_report(out, studies, quick=quick, seconds=seconds, machine=machine)
    results = {"task": "challenges", "quick": quick, "seconds": seconds, "machine": machine,
               "studies": {n: {k: v for k, v in s.items() if k != "markdown"}
                           for n, s in studies.items()}}
    path = out / "results.json"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(results, indent=1, allow_nan=False, default=_jsonable))
    tmp.replace(path)
    outputs.record(out, outputs.written_files(out))
    log(f"report: {report}")
    return out, report, results, seconds


def _targets(studies: dict[str, dict]) -> list[str]:
    """The table of targets: every study's ``results["targets"]`` entries
    ``{"what", "target", "measured", "met"}``."""
    rows = []
    for name, title in STUDIES:
        for t in (studies.get(name, {}).get("results") or {}).get("targets", []) or []:
            met = t.get("met")
            word = "met" if met is True else ("missed" if met is False else "–")
            rows.append(f"| {title.split('.')[0]} | {t.get('what', '')} | {t.get('target', '')} "
                        f"| {t.get('measured', '')} | {word} |")
    if not rows:
        return []
    return ["| challenge | what | target | measured | |", "|---|---|---|---|---|", *rows, ""]


def write_report(out: Path, studies: dict[str, dict], *, quick: bool, seconds: float,
                 machine: str) -> Path:
    """``report.md``: what was run, the targets, then each study's own section."""
    lines = ["# The paper's open challenges (Section VI-B), solved and measured", ""]
    if quick:
        lines += ["**This is a quick run**: tiny data and short training, to check the studies "
                  "in minutes; its numbers are not the studies' results (run without `--quick` "
                  "for those), and its figures are screen-resolution drafts.", ""]
    lines += [f"`softpinn reproduce challenges{' --quick' if quick else ''}`; wall time "
              f"{seconds:.0f} s on {machine or 'this machine'} (per study: "
              + ", ".join(f"{n} {s.get('seconds', 0.0):.0f} s" for n, s in studies.items())
              + ").", ""]
    lines += _targets(studies)
    for name, title in STUDIES:
        s = studies.get(name)
        if s is None:
            continue
        body = [("#" + ln) if ln.startswith("#") else ln  # a study's headings go under ours
                for ln in s.get("markdown", "").strip().splitlines()]
        lines += [f"## {title}", "", *body, ""]
    report = out / "report.md"
    tmp = report.with_name(report.name + ".tmp")
    tmp.write_text("\n".join(lines), "utf-8")
    tmp.replace(report)
    return report
