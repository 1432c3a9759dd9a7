"""Rollout figures of a task report: one panel per coordinate, named with its unit, the truth and
every model from the same initial state, and the error against time on a log axis below.

A rollout that diverged (a non-finite value, or one a thousand times the truth's range away from
it) is drawn up to where it left and marked there "diverged at t = ... s"; nothing non-finite
reaches a log axis (matplotlib's log axis fails on infinity: issue 15's task4 crash).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from softpinn.bridge.figures.figsave import save_for_print
from softpinn.bridge.figures.large_arms import input_blocks, is_large, segment_count

NETWORK = {"lagrangian": "Lagrangian", "hamiltonian": "Hamiltonian", "blackbox": "black box"}
COLORS = {"lagrangian": "C0", "hamiltonian": "C3", "blackbox": "C1"}
STYLES = {"lagrangian": "--", "hamiltonian": "-.", "blackbox": ":"}
#: How far outside the truth's range (in multiples of it) a prediction counts as diverged.
DIVERGED_FACTOR = 1e3
#: The fewest trajectories whose errors are summarised by a median and a 10-90 % band; fewer
#: are drawn one by one (a band of two trajectories says nothing a reader can use).
MIN_BAND = 5


def finite_percentile(a: np.ndarray, p: float) -> np.ndarray:
    """The ``p``-th percentile of each column of ``a`` (2-D) over its finite entries, as
    ``np.nanpercentile(a, p, axis=0)`` with non-finite entries as NaN (linear interpolation);
    NaN for a column with none. Vectorised: numpy's nanpercentile runs a Python loop per column
    once any NaN is present, 55 of the 139 s of task 5's report (10 s rollouts at 1000 Hz)."""
    a = np.asarray(a, float)
    finite = np.isfinite(a)
    s = np.sort(np.where(finite, a, np.inf), axis=0)  # the finite first, in order
    count = finite.sum(axis=0)
    pos = (p / 100.0) * np.maximum(count - 1, 0)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
    cols = np.arange(a.shape[1])
    frac = pos - lo
    with np.errstate(invalid="ignore"):
        v = s[lo, cols] * (1.0 - frac) + s[hi, cols] * frac
        v = np.where(frac == 0.0, s[lo, cols], v)  # no inf * 0 at an exact rank
    return np.where(count > 0, v, np.nan)


def diverged_at(q_pred: np.ndarray, q_true: np.ndarray) -> int | None:
    """The first sample where the prediction is not finite or is farther from the truth than
    :data:`DIVERGED_FACTOR` times the truth's range (None: it stayed)."""
    q_pred = np.asarray(q_pred, float)
    q_true = np.asarray(q_true, float)
    scale = float(np.ptp(q_true)) if q_true.size else 0.0
    scale = max(scale, float(np.max(np.abs(q_true))) if q_true.size else 0.0, 1e-9)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~np.all(np.isfinite(q_pred), axis=1)
        bad |= np.max(np.abs(np.nan_to_num(q_pred - q_true, nan=np.inf)), axis=1) > (
            DIVERGED_FACTOR * scale)
    idx = np.flatnonzero(bad)
    return int(idx[0]) if idx.size else None


def rollout_figure(t: np.ndarray, q_true: np.ndarray, predictions: Mapping[str, np.ndarray], *,
                   names: Sequence[str], units: Sequence[str], title: str, path: str | Path,
                   u: np.ndarray | None = None, dpi: int | None = None,
                   bands: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None) -> Path:
    """Write the figure: a panel per coordinate, the error panel and, given ``u`` (T, m), the
    inputs the models were driven by (see the module). ``bands``: per model ``(t (T,), errors
    (K, T))`` of every test trajectory (times since each rollout's start): the error panel
    shades their 10-90 % band behind the drawn trajectory's error, so the one trajectory
    drawn is seen against all the others."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(t, float)
    q_true = np.asarray(q_true, float)
    n = q_true.shape[1]
    cols = min(3, n)
    rows = -(-n // cols)
    inputs = u is not None and np.asarray(u).ndim == 2 and np.asarray(u).shape[1] > 0
    groups = _input_groups(np.asarray(u).shape[1], names, n) if inputs else []
    u_rows = -(-len(groups) // cols) if len(groups) > 1 else 1
    extra = 1 + u_rows if inputs else 1
    fig = plt.figure(figsize=(3.6 * cols + 0.6, 2.3 * rows + 2.6 + 1.6 * (extra - 1)),
                     layout="constrained")
    grid = fig.add_gridspec(rows + extra, cols, height_ratios=[1.0] * rows + [1.1] * extra)
    axes = [fig.add_subplot(grid[i // cols, i % cols]) for i in range(n)]
    err_ax = fig.add_subplot(grid[rows, :])
    if inputs and len(groups) > 1:  # a large arm's: one panel per segment's inputs
        _draw_input_groups(fig, grid, rows, cols, t, np.asarray(u, float), groups, err_ax)
    elif inputs:
        u = np.asarray(u, float)
        u_ax = fig.add_subplot(grid[rows + 1, :], sharex=err_ax)
        for j in range(u.shape[1]):
            u_ax.plot(t[: len(u)], u[: len(t), j], lw=1.0, label=f"u{j + 1}")
        u_ax.set_ylabel("inputs u")
        u_ax.set_xlabel("t [s]")
        u_ax.grid(alpha=0.3)
        u_ax.legend(fontsize=7, ncols=min(u.shape[1], 6), loc="upper right")
    cut = {k: diverged_at(qp, q_true) for k, qp in predictions.items()}
    for i, ax in enumerate(axes):
        ax.plot(t, q_true[:, i], "k-", lw=1.6, label="truth")
        for k, qp in predictions.items():
            end = cut[k] if cut[k] is not None else len(t)
            ax.plot(t[:end], np.asarray(qp, float)[:end, i], STYLES.get(k, "--"), lw=1.3,
                    color=COLORS.get(k, "C2"), label=NETWORK.get(k, k))
            if cut[k] is not None:
                ax.plot(t[max(end - 1, 0)], q_true[max(end - 1, 0), i], "x", ms=8, mew=2,
                        color=COLORS.get(k, "C2"))
        _focus(ax, q_true[:, i], [np.asarray(qp, float)[:, i] for qp in predictions.values()])
        unit = f" [{units[i]}]" if units[i] else ""
        ax.set_ylabel(f"{names[i]}{unit}")
        ax.grid(alpha=0.3)
        if i // cols == rows - 1 or i + cols >= n:
            ax.set_xlabel("t [s]")
    handles, labels = axes[0].get_legend_handles_labels()
    # below the figure: constrained layout does not stack an outside legend under the title
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=8,
               frameon=False)
    fig.suptitle(title, fontsize=10, x=0.02, ha="left")
    notes = []
    bands = {k: b for k, b in (bands or {}).items()
             if np.asarray(b[1]).ndim == 2 and np.asarray(b[1]).shape[0] >= MIN_BAND}
    for k, (bt, berr) in bands.items():
        bt, berr = np.asarray(bt, float), np.asarray(berr, float)
        if bt.size < 2:
            continue
        keep = (bt > bt[0]) & (bt - bt[0] <= t[-1] - t[0] + 1e-12)
        lo, hi = (finite_percentile(berr, p) for p in (10, 90))
        ok = keep & np.isfinite(lo) & np.isfinite(hi)
        if ok.any():
            err_ax.fill_between(t[0] + bt[ok] - bt[0], np.maximum(lo[ok], 1e-16),
                                np.maximum(hi[ok], 1e-16), color=COLORS.get(k, "C2"),
                                alpha=0.15, lw=0)
    if bands:
        count = max((np.asarray(b[1]).shape[0] for b in bands.values()), default=0)
        err_ax.set_title(f"error of the trajectory drawn; shaded: 10-90 % of all {count} test "
                         "trajectories", fontsize=8, loc="left")
    for k, qp in predictions.items():
        qp = np.asarray(qp, float)
        end = cut[k] if cut[k] is not None else len(t)
        if end > 1:
            err = np.max(np.abs(qp[1:end] - q_true[1:end]), axis=1)
            err_ax.semilogy(t[1:end], np.maximum(err, 1e-16), STYLES.get(k, "--"), lw=1.3,
                            color=COLORS.get(k, "C2"), label=NETWORK.get(k, k))
        if cut[k] is not None:
            notes.append(f"{NETWORK.get(k, k)} diverged at t = {t[end]:.3g} s")
    if notes:
        err_ax.text(0.01, 0.95, "; ".join(notes), transform=err_ax.transAxes, va="top",
                    fontsize=8, color="C3", bbox={"facecolor": "white", "alpha": 0.8,
                                                  "edgecolor": "none"})
    same = units[0] if units and all(u == units[0] for u in units) and units[0] else ""
    err_ax.set_ylabel("max over q of |q − q̂|" + (f" [{same}]" if same else ""))
    err_ax.set_xlabel("t [s]")
    err_ax.set_xlim(t[0], t[-1])
    err_ax.grid(alpha=0.3, which="both")
    path = Path(path)
    save_for_print(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def _input_groups(m: int, names: Sequence[str], n: int) -> list[tuple[str, list[int]]]:
    """The inputs of a large arm (:func:`bridge.figures.large_arms.is_large`) grouped by
    segment, (title, indices) each; one group (today's single panel) for a small arm."""
    if not is_large(n, m):
        return [("", list(range(m)))]
    segments = segment_count(names, n)
    blocks = input_blocks(m, segments)
    if segments > 1 and len(blocks) == segments:
        return [(f"inputs of segment {s + 1} ({lab})", idx) for s, (lab, idx) in
                enumerate(blocks)]
    return [(f"inputs {lab}", idx) for lab, idx in blocks]


def _draw_input_groups(fig, grid, rows: int, cols: int, t: np.ndarray, u: np.ndarray,
                       groups, err_ax) -> None:
    """One panel per group of inputs below the error panel, ``cols`` to a row, each input in a
    colour of its own within its panel (a linestyle too past ten), named in the panel's
    legend."""
    styles = ("-", "--", ":", "-.")
    for g, (title, idx) in enumerate(groups):
        ax = fig.add_subplot(grid[rows + 1 + g // cols, g % cols], sharex=err_ax)
        for c, j in enumerate(idx):
            ax.plot(t[: len(u)], u[: len(t), j], styles[(c // 10) % len(styles)], lw=1.0,
                    color=f"C{c % 10}", label=f"u{j + 1}")
        ax.set_title(title, fontsize=8, loc="left")
        if g % cols == 0:
            ax.set_ylabel("inputs u")
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncols=min(len(idx), 4), loc="upper right")


def horizon_figure(curves: Mapping[str, tuple[np.ndarray, np.ndarray]], *, title: str,
                   path: str | Path, dpi: int | None = None, unit: str = "") -> Path:
    """How far ahead a model can be trusted: for each model the error max over q of
    |q - q_hat| against the time since the start, over every test trajectory (``curves[kind] =
    (t (T,), errors (K, T))``): the median as a line, the 10-90 % band shaded, log scale. A
    trajectory counts as diverged (inf) from where it left; the band then reaches the top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
    finite_max = 1e-16
    for _, err in curves.values():
        err = np.asarray(err, float)
        if err.size:
            ok = err[np.isfinite(err)]
            finite_max = max(finite_max, float(ok.max()) if ok.size else finite_max)
    top = finite_max * 10
    notes: list[str] = []
    for k, (t, err) in curves.items():
        err = np.clip(np.asarray(err, float)[:, 1:], 1e-16, top)
        t = np.asarray(t, float)[1:]
        if not err.size:
            continue
        color = COLORS.get(k, "C2")
        if len(err) >= MIN_BAND:
            lo, mid, hi = np.percentile(err, [10, 50, 90], axis=0)
            ax.semilogy(t, mid, STYLES.get(k, "-"), color=color, lw=1.5,
                        label=f"{NETWORK.get(k, k)} (median of {len(err)}, 10-90 % shaded)")
            ax.fill_between(t, lo, hi, color=color, alpha=0.18, lw=0)
        else:  # too few for a band: each trajectory
            for r, row in enumerate(err):
                ax.semilogy(t, row, STYLES.get(k, "-"), color=color, lw=1.1,
                            label=f"{NETWORK.get(k, k)} (each of {len(err)})" if r == 0 else None)
        gone = int(np.sum(np.asarray(curves[k][1], float)[:, -1] >= top))
        if gone:
            notes.append(f"{NETWORK.get(k, k)}: {gone} of {len(err)} diverged (drawn at the top)")
    if notes:
        ax.text(0.01, 0.97, "; ".join(notes), transform=ax.transAxes, va="top", fontsize=8,
                color="C3", bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax.set_ylim(top=top * 3 if notes else finite_max * 3)  # room above only for the diverged
    ax.set_xlabel("time since the start of the rollout [s]")
    ax.set_ylabel("max over q of |q − q̂|" + (f" [{unit}]" if unit else ""))
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    path = Path(path)
    save_for_print(fig, path, dpi=dpi)
    plt.close(fig)
    return path


def _focus(ax, truth: np.ndarray, preds: Sequence[np.ndarray]) -> None:
    """y-limits around the truth and the predictions near it: a prediction that runs away is
    cut at the panel's edge (the error panel below shows how far), not allowed to flatten the
    truth into a line."""
    lo, hi = float(np.min(truth)), float(np.max(truth))
    span = max(hi - lo, 1e-3 * max(abs(lo), abs(hi)), 1e-9)
    window = (lo - 2 * span, hi + 2 * span)
    for p in preds:
        near = p[np.isfinite(p) & (p >= window[0]) & (p <= window[1])]
        if near.size:
            lo, hi = min(lo, float(near.min())), max(hi, float(near.max()))
    pad = 0.08 * (hi - lo) + 1e-12
    ax.set_ylim(lo - pad, hi + pad)


def finite_points(x: Sequence[float], y: Sequence[float], err: Sequence[float] | None = None):
    """The points of a log-log curve that can be drawn (finite, positive) and the x of those
    that cannot (a diverged model's infinite error)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    e = np.zeros_like(y) if err is None else np.nan_to_num(np.asarray(err, float), nan=0.0,
                                                             posinf=0.0)
    ok = np.isfinite(y) & (y > 0) & np.isfinite(x)
    return x[ok], y[ok], e[ok], x[~ok]
