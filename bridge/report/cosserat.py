"""The report of ``softpinn reproduce cosserat`` (``OUT/report.md``, :mod:`bridge.cosserat`): one
table of rollout errors on the held-out trajectories, the networks beside no motion and the
linear models, clean and with sensor noise; one verdict line per network per
variant (:func:`bridge.analysis.baselines.verdict`); and the settings that made them."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softpinn.bridge.analysis.baselines import BASELINES
from softpinn.bridge.cosserat import NETWORKS, CosseratRun
from softpinn.bridge.figures.tables import format_mean_std
from softpinn.files import atomic_write

#: the table's rows: the baselines, then the networks (label, what, kind)
ROWS = (
    *((name, "baseline", kind) for name, kind, _ in BASELINES),
    *((label, "network", kind) for kind, label in NETWORKS),
)


def _horizons(variant: Mapping[str, Any]) -> list[float]:
    """The horizons a variant was scored at (within its test trajectories), shortest first."""
    return sorted({float(s["horizon"]) for s in variant["baselines"]["scores"]})


def columns(results: Mapping[str, Any]) -> list[tuple[str, float]]:
    """(variant, horizon) of each column: every variant at every horizon (the verdicts speak
    of each)."""
    return [(v, h) for v in ("clean", "noisy") if v in results for h in _horizons(results[v])]


def _marks(count: int, tested: int, diverged: int = 0) -> str:
    parts = []
    if diverged:
        parts.append(f"{diverged} of {tested} diverged")
    if count:
        parts.append(f"{count} of {tested} left the training range")
    return f" ({'; '.join(parts)})" if parts else ""


def cell(variant: Mapping[str, Any], what: str, kind: str, horizon: float) -> str:
    """One model's rollout error at ``horizon``: mean ± std over the test trajectories [rad²];
    "diverged" where a rollout left the finite numbers, a mark where one left the training
    range, never a silent number."""
    tested = len(variant["import"]["test"])
    if what == "baseline":
        s = next(s for s in variant["baselines"]["scores"]
                 if s["kind"] == kind and math.isclose(float(s["horizon"]), horizon))
        if s["mean"] is None:
            return "diverged" + _marks(len(s["out_of_range"]), tested)
        return format_mean_std(s["mean"], s["std"]) + _marks(len(s["out_of_range"]), tested)
    pred = variant["networks"][kind]["predict"]
    if pred.get("missing"):
        return f"no model ({pred['missing']})"
    h = next((v for v in pred["horizons"].values() if math.isclose(float(v["horizon"]),
                                                                     horizon)), None)
    if h is None:
        return "—"
    marks = _marks(len(h["out_of_range"]), tested, int(h["diverged"]))
    if h["mean"] is None:
        return "diverged" + marks
    return format_mean_std(h["mean"], h["std"]) + marks


def table(results: Mapping[str, Any]) -> list[str]:
    """The Markdown table: one row per model of :data:`ROWS`, one column per :func:`columns`."""
    cols = columns(results)
    head = "| model | " + " | ".join(f"{v} {h:g} s" for v, h in cols) + " |"
    lines = [head, "|---" * (len(cols) + 1) + "|"]
    for label, what, kind in ROWS:
        cells = [cell(results[v], what, kind, h) for v, h in cols]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def _training_lines(variant: str, v: Mapping[str, Any]) -> list[str]:
    imp = v["import"]
    lines = [f"- **{variant}**: smoother `{imp['smooth']}`; trajectories: train "
             f"{imp['train']}, validation {imp['validation']} (best epoch), test {imp['test']}; "
             f"bending rms {imp['q_rms']:.3g} rad"]
    act = v.get("actuator")
    if act:
        told = (act.get("note") or act["describe"]).removeprefix("actuator: ")
        lines.append(f"  - actuator (every network and baseline): {told}")
    chose = sorted({f"{s['name']} {s['detail']}" for s in v.get("baselines", {}).get("scores", [])
                    if s.get("detail")})
    if chose:  # what a baseline's fit chose (the lagged ARX's order and fit)
        lines.append("  - baselines: " + "; ".join(chose))
    for kind, label in NETWORKS:
        n = v["networks"][kind]
        t = n["train"]
        if t.get("diverged"):
            lines.append(f"  - {label}: training diverged ({t['diverged']})")
            continue
        m = t.get("metrics") or {}
        one_step = next((h.get("one_step_error") for h in n["predict"]["horizons"].values()),
                        None)
        member = (m.get("members") or [{}])[0]
        parts = [f"{t.get('epochs')} epochs on {t.get('pairs')} pairs"]
        if isinstance(member.get("best_test_loss"), (int, float)):
            parts.append(f"best validation loss {member['best_test_loss']:.3g} at epoch "
                         f"{member.get('best_epoch')} ({member.get('stopped')})")
        if isinstance(member.get("seconds"), (int, float)):
            parts.append(f"{member['seconds']:.0f} s to train")
        if one_step is not None:
            parts.append(f"one-step test error {one_step:.3g}")
        lines.append(f"  - {label}: " + ", ".join(parts))
        lines += [f"    - warning: {w}" for w in t.get("warnings", [])]
    return lines


def _settings_lines(run: CosseratRun) -> list[str]:
    p = run.plan
    lines = [
        f"- recordings: {p.trajectories} trajectories of {p.duration_s:g} s at {p.rate_hz:g} Hz "
        f"per variant (seed {p.seed}; the same motion in both), the last {p.test_trajectories} "
        f"held out for test, the {p.validation_trajectories} before them for validation; sensor "
        + ", ".join(f"{k} {float(v['noise']):g} rad" for k, v in p.variants.items())
        + "; the arm's settings in `<variant>/record/cosserat.json`",
        "- import: `softpinn import REC*.csv --model experiment --orientation quaternion "
        f"--test-trajectories {p.test_trajectories} --smooth S` (clean: "
        f"`{p.variants['clean']['smooth']}`, noisy: `{p.variants['noisy']['smooth']}`); the "
        "networks train on the bending (dx, dy) only: a tip orientation does not see the "
        "stretch",
        f"- actuator: `--actuator {p.actuator}` (the stand-in's own lag and dead time are in "
        "`<variant>/record/cosserat.json`; the study does not give them to the models)",
        f"- prior: `--prior {getattr(p, 'prior', 'auto')}` (auto: the networks start as the "
        "linear model of their training trajectories, fitted by least squares or by its rollout "
        "error, whichever rolls out better, and learn the correction; epoch 0 is that model, "
        "so the validation score keeps it unless training finds better)",
        f"- best epoch: `--test-with {getattr(p, 'test_with', 'loss')}` (rollout: the "
        "validation trajectories' rollout error over up to 5 s picks it)",
        f"- training: loss `{p.loss}`, input hold `{p.input_hold}`, batch {p.batch_size}, "
        f"{'all pairs' if p.samples is None else f'{p.samples} pairs'}, float64, seed "
        f"{p.train_seed}",
    ]
    for n in p.networks:
        sizes = (f"hidden {tuple(n.hidden)}" if n.kind == "blackbox" else
                 f"mass {tuple(n.mass)}, potential {tuple(n.potential)}, damping "
                 f"{tuple(n.damping)}, input {tuple(n.input)}")
        extra = ", momenta from velocities" if n.momenta == "velocity" else ""
        lines.append(f"  - {n.kind}: {sizes}, {n.epochs} epochs, lr {n.lr:g}{extra}")
    lines.append("- every setting: `plan.json`; every number: `results.json`")
    return lines


def write_cosserat_report(run: CosseratRun, *, seconds: float, machine: str) -> Path:
    """``report.md`` of a finished run."""
    r = run.results
    lines = ["# Learned models against linear ones on a Cosserat-rod arm (not PCC)", ""]
    if run.plan.quick:
        lines += ["**This is a quick run**: three short recordings and a few epochs, to check "
                  "the study in a minute or two; its numbers are not the study's results (run "
                  "without `--quick` for those).", ""]
    lines += [
        f"`softpinn reproduce cosserat{' --quick' if run.plan.quick else ''}`; the stages took "
        f"{sum(run.stage_seconds.values()):.0f} s when they ran (this call {seconds:.0f} s) on "
        f"{machine or 'this machine'}.", "",
        "A Cosserat rod with a heavy tip (PyElastica), actuated by four tip moments through a "
        "dead time and a first-order lag, recorded by a tip orientation sensor and imported as "
        "a real arm's recordings are (docs/cosserat.md). Rollout error on the held-out test "
        "trajectories (`softpinn predict`'s metric: mean over the samples of ‖q - q̂‖², rad², "
        "from the true initial state under the true inputs, no reset), mean ± std over the "
        "test trajectories:", "",
        *table(r), "",
        "## Verdicts", "",
    ]
    for variant in r:
        lines += [f"- {variant}: {line}" for line in r[variant]["verdicts"].values()]
    lines += ["", "## Training", ""]
    for variant, v in r.items():
        lines += _training_lines(variant, v)
    lines += ["", "## Settings", "", *_settings_lines(run), ""]
    report = run.out / "report.md"
    atomic_write(report, "\n".join(lines))
    return report
