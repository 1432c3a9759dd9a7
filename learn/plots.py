"""Plots of training and prediction: loss curves (like Figs. 21-22) and rollouts against the
truth (like Figs. 8 and 23). Uses matplotlib's object API with the Agg canvas: no pyplot, no
global backend state; every function writes one PNG atomically and returns its path.

Every PNG carries ``Software: softpinn`` in its metadata (:data:`SOFTWARE`), which is how
:func:`written_by_softpinn` tells a plot softpinn may overwrite from a user's file. Non-finite
values (a diverged rollout or loss) are left out of the curves, never passed to a log axis."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from softpinn.errors import UserError
from softpinn.learn._checkpoint import atomic_write_bytes

SOFTWARE = "softpinn"
_PNG = b"\x89PNG\r\n\x1a\n"


def written_by_softpinn(path: str | Path) -> bool:
    """Whether ``path`` is a PNG that softpinn wrote (its metadata names softpinn)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return head.startswith(_PNG) and b"Software\x00" + SOFTWARE.encode() in head


def check_may_write(path: str | Path, *, force: bool = False) -> Path:
    """Refuse to overwrite ``path`` unless it does not exist, is a plot softpinn wrote, or
    ``force``; refuse a folder always."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"plot: {path} is a folder, not a file")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"plot: {path}: {parent} is a file, not a folder")
            break
    if path.exists() and not force and not written_by_softpinn(path):
        raise UserError(
            f"plot: {path} exists and was not written by softpinn; refusing to overwrite it "
            "(choose another file, or force it)"
        )
    return path


def _finite(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    return np.where(np.isfinite(a), a, np.nan)


def _figure(rows: int = 1, cols: int = 1, *, size=(7.0, 4.0)):
    # matplotlib is imported at the first figure, not with softpinn (slow to import)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def _save(fig, path: str | Path, record: bool = False) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, metadata={"Software": SOFTWARE})
    return atomic_write_bytes(path, buf.getvalue(), record=record)


def plot_loss_curves(
    histories: Sequence[Sequence[dict]],
    path: str | Path,
    *,
    labels: Sequence[str] | None = None,
    title: str = "training",
    record: bool = False,
    colors: Sequence[str] | None = None,
) -> Path:
    """Train (solid) and test (dashed) loss against epoch, log scale, one colour per run
    (``colors``: one per run, e.g. the colours the run's model has in a report's other
    figures)."""
    fig, axes = _figure()
    ax = axes[0, 0]
    for i, hist in enumerate(histories):
        if not hist:
            continue
        e = np.array([r["epoch"] for r in hist])
        tr = _finite([r["train_loss"] for r in hist])
        te = _finite([r["test_loss"] for r in hist])
        lab = labels[i] if labels else None
        color = colors[i] if colors else None
        (line,) = ax.plot(e, tr, lw=1.2, color=color, label=f"train {lab}" if lab else "train")
        ax.plot(e, te, "--", lw=1.2, color=line.get_color(), label=f"test {lab}" if lab else "test")
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("loss")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    if len(histories) <= 8 and ax.get_lines():
        ax.legend(fontsize=8)
    return _save(fig, path, record)


def coordinate_unit(name: str, kind: str | None) -> str:
    """The unit of a coordinate from its name (``theta1`` -> rad, ``dL2`` -> m) and the spec's
    kind (the double pendulum's angles, the mass-spring-damper's positions); '' if unknown."""
    base = str(name).rstrip("0123456789")
    if base in ("theta", "phi") or kind == "double-pendulum":
        return "rad"
    if base in ("dL", "dx", "dy") or kind == "mass-spring-damper":
        return "m"
    return ""


def plot_rollout(
    t: np.ndarray,
    q_true: np.ndarray,
    q_pred: np.ndarray,
    path: str | Path,
    *,
    title: str = "rollout",
    resets: np.ndarray | None = None,
    names: list[str] | None = None,
    kind: str | None = None,
) -> Path:
    """Predicted (dashed) against true (solid) coordinates over time, one panel per coordinate
    (``names``, e.g. the data file's ``dx1``, ``dy1``, ``dL1``, with units from ``kind``), and
    the absolute errors underneath. Time runs from the trajectory's first sample. A prediction
    that leaves the truth's range far behind (or runs away) is cut at the panel's edge, which
    says so, so that the true curve stays readable."""
    n = q_true.shape[1]
    names = list(names) if names is not None and len(names) == n else [
        f"q{i + 1}" for i in range(n)]
    units = [coordinate_unit(c, kind) for c in names]
    t0 = float(np.asarray(t, float)[0])
    t = np.asarray(t, float) - t0
    q_pred = _finite(q_pred)
    fig, axes = _figure(n + 1, 1, size=(7.0, 1.8 * (n + 1)))
    for i in range(n):
        ax = axes[i, 0]
        ax.plot(t, q_true[:, i], lw=1.4, label="true")
        ax.plot(t, q_pred[:, i], "--", lw=1.4, label="predicted")
        ax.set_ylabel(f"{names[i]} [{units[i]}]" if units[i] else names[i])
        ax.grid(True, alpha=0.3)
        lo, hi = float(np.min(q_true[:, i])), float(np.max(q_true[:, i]))
        span = max(hi - lo, 1e-12 + 1e-6 * max(abs(lo), abs(hi)))
        with np.errstate(invalid="ignore"):
            outside = (q_pred[:, i] < lo - 2 * span) | (q_pred[:, i] > hi + 2 * span)
        if np.isnan(q_pred[:, i]).any() or outside.any():
            ax.set_ylim(lo - 2 * span, hi + 2 * span)
            ax.text(0.99, 0.04, "prediction leaves the panel", transform=ax.transAxes,
                    ha="right", va="bottom", fontsize=7, color="C1")
        if resets is not None:
            for tr in np.asarray(resets, float) - t0:
                ax.axvline(tr, color="0.7", lw=0.6)
    axes[0, 0].legend(fontsize=8)
    axes[0, 0].set_title(title)
    ax = axes[n, 0]
    # the error is zero at t0 (the true initial state): plot from the first step on
    with np.errstate(invalid="ignore", over="ignore"):
        err = _finite(np.maximum(np.abs(q_pred - q_true)[1:], 1e-300))
    for i in range(n):  # past ten coordinates (a 4-segment arm) the colours repeat: restyle
        ax.plot(t[1:], err[:, i], ("-", "--", ":", "-.")[(i // 10) % 4], lw=1.0,
                color=f"C{i % 10}", label=f"|{names[i]} error|")
    ax.legend(fontsize=7, ncol=min(n, 3))
    ax.set_yscale("log")
    ax.set_xlabel("time from the trajectory's start [s]")
    same = units[0] if units and all(u == units[0] for u in units) else ""
    ax.set_ylabel(f"abs. error [{same}]" if same else "abs. error")
    ax.grid(True, which="both", alpha=0.3)
    return _save(fig, path)
