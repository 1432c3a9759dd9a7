"""The figures of the experiment's report (:mod:`bridge.report.experiment`): predictions against
the true arm and the processed measurement, raw against processed data (Fig. 52), the simulated
IMU's error, and the rate study. Every axis is named with its unit."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.figures.figsave import save_for_print
from softpinn.bridge.figures.rollouts import COLORS, NETWORK, STYLES, diverged_at, finite_points

KINDS = ("lagrangian", "blackbox")
PREP_TITLE = {"none": "none", "movmean": "moving average", "polyfit": "polynomial fits",
              "savgol": "Savitzky-Golay"}
PREP_COLOR = {"none": "0.45", "movmean": "C2", "polyfit": "C4", "savgol": "C5"}
BEND = ("dx1", "dy1")
#: with the preset's d = 1 m, dx and dy in m are the bending angle's components in rad
UNIT = "rad"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def rollout_plot(path: Path, t, measured, truth, predictions: Mapping[str, np.ndarray], *,
                 resets: Sequence[float] = (), title: str) -> Path:
    """dx, dy of the true arm, the processed measurement and each model's prediction from the
    measurement's state, with the error against the true arm on a log axis below; a prediction
    that diverges is drawn up to where it left and marked."""
    plt = _plt()
    t = np.asarray(t, float)
    fig = plt.figure(figsize=(9.0, 5.6), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 0.9])
    axes = [fig.add_subplot(grid[0, i]) for i in range(2)]
    err_ax = fig.add_subplot(grid[1, :])
    cut = {k: diverged_at(np.asarray(qp)[:, :2], np.asarray(truth)[:, :2])
           for k, qp in predictions.items()}
    for i, ax in enumerate(axes):
        ax.plot(t, truth[:, i], "k-", lw=1.6, label="true arm")
        ax.plot(t, measured[:, i], "o", ms=2.5, color="0.55", label="processed measurement")
        lo, hi = float(np.min(truth[:, i])), float(np.max(truth[:, i]))
        for k, qp in predictions.items():
            end = cut[k] if cut[k] is not None else len(t)
            ax.plot(t[:end], np.asarray(qp)[:end, i], STYLES.get(k, "--"), lw=1.4,
                    color=COLORS.get(k, "C2"), label=NETWORK.get(k, k))
            if cut[k] is not None:
                ax.plot(t[max(end - 1, 0)], truth[max(end - 1, 0), i], "x", ms=8, mew=2,
                        color=COLORS.get(k, "C2"))
        span = max(hi - lo, 1e-6)
        ax.set_ylim(lo - 0.6 * span, hi + 0.6 * span)
        for r in resets:
            ax.axvline(r, color="0.8", lw=0.8, zorder=0)
        ax.set_ylabel(f"{BEND[i]} [{UNIT}]")
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=8,
               frameon=False)
    fig.suptitle(title, fontsize=10, x=0.02, ha="left")
    notes = []
    for k, qp in predictions.items():
        qp = np.asarray(qp, float)
        end = cut[k] if cut[k] is not None else len(t)
        if end > 1:
            e = np.max(np.abs(qp[1:end, :2] - truth[1:end, :2]), axis=1)
            err_ax.semilogy(t[1:end], np.maximum(e, 1e-12), STYLES.get(k, "--"), lw=1.3,
                            color=COLORS.get(k, "C2"), label=NETWORK.get(k, k))
        if cut[k] is not None:
            notes.append(f"{NETWORK.get(k, k)} diverged at t = {t[end]:.3g} s")
    e = np.max(np.abs(measured[1:, :2] - truth[1:, :2]), axis=1)
    err_ax.semilogy(t[1:], np.maximum(e, 1e-12), "o", ms=2, color="0.55",
                    label="processed measurement")
    for r in resets:
        err_ax.axvline(r, color="0.8", lw=0.8, zorder=0)
    if notes:
        err_ax.text(0.01, 0.95, "; ".join(notes), transform=err_ax.transAxes, va="top",
                    fontsize=8, color="C3")
    err_ax.set_ylabel(f"max(|Δdx|, |Δdy|) from the true arm [{UNIT}]", fontsize=8)
    err_ax.set_xlabel("t [s]")
    err_ax.set_xlim(t[0], t[-1])
    err_ax.grid(alpha=0.3, which="both")
    save_for_print(fig, path)
    plt.close(fig)
    return path


def raw_figure(path: Path, t, q_true, qd_true, processed: Mapping[str, tuple], *,
               title: str) -> Path:
    """Fig. 52's comparison: the measured bending and its velocity as imported with each
    preprocessing, against the true arm."""
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(10.0, 6.0), layout="constrained", sharex=True)
    for row, (truth, what, unit) in enumerate(((q_true, "", UNIT), (qd_true, "d/dt ",
                                                                    f"{UNIT}/s"))):
        for i in range(2):
            ax = axes[row, i]
            ax.plot(t, truth[:, i], "k-", lw=1.8, label="true arm")
            for p, arrays in processed.items():
                y = arrays[row][:, i]
                if p == "none":
                    ax.plot(t, y, "o", ms=2.5, color=PREP_COLOR[p], label="raw (none)")
                else:
                    ax.plot(t, y, "-", lw=1.1, color=PREP_COLOR.get(p, "C6"),
                            label=f"{PREP_TITLE.get(p, p)}")
            lo, hi = float(truth[:, i].min()), float(truth[:, i].max())
            span = max(hi - lo, 1e-6)
            ax.set_ylim(lo - 0.5 * span, hi + 0.5 * span)
            ax.set_ylabel(f"{what}{BEND[i]} [{unit}]")
            ax.grid(alpha=0.3)
            if row == 1:
                ax.set_xlabel("t [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=8,
               frameon=False)
    fig.suptitle(title, fontsize=10, x=0.02, ha="left")
    save_for_print(fig, path)
    plt.close(fig)
    return path


def sensor_figure(path: Path, t, angles, angles_true, bias, *, title: str) -> Path:
    """The IMU's error on each angle (measured − true) and its drifting bias."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(10.0, 3.0), layout="constrained", sharey=True)
    for i, name in enumerate(("roll", "pitch", "yaw")):
        ax = axes[i]
        ax.plot(t, angles[:, i] - angles_true[:, i], "o", ms=2, color="0.5",
                label="measured − true")
        ax.plot(t, bias[:, i], "C3-", lw=1.4, label="bias (random walk)")
        ax.set_xlabel("t [s]")
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("angle error [rad]")
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10, x=0.02, ha="left")
    save_for_print(fig, path)
    plt.close(fig)
    return path


def rate_figure(path: Path, results: Mapping[str, Any], *, horizon: float) -> Path:
    """Prediction error against the true arm by sensor rate, a line per preprocessing, a panel
    per model; a diverged point is named below the panel."""
    plt = _plt()
    rates = [float(rn[:-2]) for rn in results["rates"]]
    preps = list(next(iter(results["rates"].values()))["preprocessing"])
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 3.8), layout="constrained", sharey=True)
    for ax, kind in zip(axes, KINDS, strict=True):
        notes = []
        for p in preps:
            vals, errs = [], []
            for per in results["rates"].values():
                e = per["preprocessing"][p]["models"][kind]["predict"]["prediction_error_truth"]
                vals.append(math.inf if e["mean"] is None else e["mean"])
                errs.append(0.0)
            x, y, _, bad = finite_points(rates, vals, errs)
            ax.loglog(x, y, "o-", color=PREP_COLOR.get(p, "C6"), label=PREP_TITLE.get(p, p))
            notes += [f"{PREP_TITLE.get(p, p)} at {b:g} Hz diverged" for b in bad]
        ax.set_title(NETWORK[kind], fontsize=10)
        ax.set_xlabel("sensor rate [Hz]")
        ax.set_xticks(rates, [f"{r:g}" for r in rates])
        ax.minorticks_off()
        ax.grid(alpha=0.3, which="both")
        if notes:
            ax.text(0.01, 0.02, "; ".join(notes), transform=ax.transAxes, fontsize=7,
                    color="C3", va="bottom")
    axes[0].set_ylabel(f"prediction error vs true arm [{UNIT}²], {horizon:g} s")
    axes[0].legend(fontsize=8)
    save_for_print(fig, path)
    plt.close(fig)
    return path
