"""The report of ``softpinn reproduce challenges`` (``OUT/report.md``): what was run, a table of
every study's targets met or missed, then each study's own section
(:mod:`bridge.challenges.pipeline` runs the studies)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from softpinn.bridge.challenges.pipeline import STUDIES


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


def write_challenges_report(out: Path, studies: dict[str, dict[str, Any]], *, quick: bool,
                            seconds: float, machine: str) -> Path:
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
