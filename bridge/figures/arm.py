"""Pictures of the arm itself: the backbone (eqs. 13-14, 27) of the true and the predicted arm
at several instants of a rollout (``shape.png``), an animation of the two over the rollout
(``shape.gif``, Pillow's GIF writer, which matplotlib installs and every browser plays), and a
single configuration or a recorded trajectory for ``softpinn show``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from softpinn.bridge.figures.figsave import is_draft, save_for_print
from softpinn.bridge.figures.rollouts import COLORS, NETWORK, diverged_at
from softpinn.symbolic import backbone_points


def _axes(fig, dim: int, where=(1, 1, 1)):
    if dim == 3:
        from matplotlib.ticker import MaxNLocator

        ax = fig.add_subplot(*where, projection="3d")
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):  # fewer ticks: the labels do not overlap
            axis.set_major_locator(MaxNLocator(4))
        ax.set_xlabel("x [m]", labelpad=8)
        ax.set_ylabel("y [m]", labelpad=8)
        ax.set_zlabel("z [m]", labelpad=8)
    else:
        ax = fig.add_subplot(*where)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.3)
    return ax


def gravity_up_axis(spec) -> bool:
    """Whether the spec's gravity points along its vertical axis's positive direction (y of a
    planar arm, z of a spatial one: a hanging arm), so that a picture turns that axis over to
    draw gravity downwards."""
    g = tuple(getattr(spec, "gravity", ()) or ())
    return len(g) in (2, 3) and g[-1] > 0


def gravity_words(spec) -> str:
    """'gravity down the page: +z' for a title, or '' where the spec has no vertical gravity."""
    g = tuple(getattr(spec, "gravity", ()) or ())
    if len(g) not in (2, 3) or g[-1] == 0:
        return ""
    return f"gravity down the page: {'+' if g[-1] > 0 else '−'}{'yz'[len(g) - 2]}"


def _with_gravity(title: str, spec) -> str:
    """``title (gravity down the page: +z)``, or the title as it is."""
    words = gravity_words(spec)
    return f"{title} ({words})" if words else title


def _limits(ax, points: np.ndarray, spec=None, margin: float = 1.1) -> tuple:
    """Equal scales on every axis around all points (T, dim, K), ``margin`` times their half
    extent; the vertical axis turned over where the spec's gravity points along it
    (:func:`gravity_up_axis`). Returns the box (lo, hi) per axis."""
    flat = points.transpose(1, 0, 2).reshape(points.shape[1], -1)
    lo, hi = np.nanmin(flat, axis=1), np.nanmax(flat, axis=1)
    mid, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2, 1e-3) * margin
    flip = spec is not None and gravity_up_axis(spec)
    if points.shape[1] == 3:
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_zlim(*((mid[2] + half, mid[2] - half) if flip else (mid[2] - half, mid[2] + half)))
        ax.set_box_aspect((1, 1, 1), zoom=0.8)
    else:
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(*((mid[1] + half, mid[1] - half) if flip else (mid[1] - half, mid[1] + half)))
    return mid - half, mid + half


def _inside(pts: np.ndarray, box) -> np.ndarray:
    """The backbone (dim, K) with the points outside the box NaN (3-D lines are not clipped)."""
    lo, hi = box
    out = np.array(pts, float)
    out[:, np.any((out < lo[:, None]) | (out > hi[:, None]), axis=0)] = np.nan
    return out


def _draw(ax, pts: np.ndarray, *, color, style="-", lw=2.0, label=None, alpha=1.0):
    """One backbone (dim, K) with its base (square) and tip (dot)."""
    args = tuple(pts)
    ax.plot(*args, style, color=color, lw=lw, label=label, alpha=alpha)
    ax.plot(*(p[:1] for p in pts), "s", color="k", ms=5, alpha=alpha)
    ax.plot(*(p[-1:] for p in pts), "o", color=color, ms=5, alpha=alpha)


def draw_configurations(spec, q, *, path: str | Path, title: str = "",
                        labels: Sequence[str] | None = None, dpi: int = 150) -> Path:
    """The backbone of each configuration in ``q`` (n,) or (k, n), one colour each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    q = np.atleast_2d(np.asarray(q, float))
    pts = backbone_points(spec, q)
    fig = plt.figure(figsize=(5.5, 5.5), layout="constrained")
    ax = _axes(fig, pts.shape[1])
    for i, p in enumerate(pts):
        label = labels[i] if labels else ("q = [" + ", ".join(f"{v:.3g}" for v in q[i]) + "]")
        _draw(ax, p, color=f"C{i % 10}", label=label)
    _limits(ax, pts, spec)
    ax.legend(fontsize=7, loc="upper left")
    words = gravity_words(spec)
    ax.set_title(title or f"{spec.name}: backbone (base ■, tip ●{'; ' + words if words else ''})",
                 fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def shape_figure(spec, t: np.ndarray, q_true: np.ndarray, predictions: Mapping[str, np.ndarray],
                 *, path: str | Path, title: str, instants: int = 4,
                 dpi: int | None = None, pdf: bool = True) -> Path:
    """The true (black) and predicted backbones at ``instants`` times of a rollout, one panel
    each; a prediction that diverged before an instant is left out of that panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(t, float)
    q_true = np.asarray(q_true, float)
    idx = np.unique(np.linspace(0, len(t) - 1, instants).round().astype(int))
    cut = {k: diverged_at(qp, q_true) for k, qp in predictions.items()}
    true_pts = backbone_points(spec, q_true[idx])
    pred_pts = {k: backbone_points(spec, np.asarray(qp, float)[idx])
                for k, qp in predictions.items() if cut[k] is None or cut[k] > idx[-1]}
    partial = {k: [i for i in range(len(idx)) if cut[k] is None or idx[i] < cut[k]]
               for k in predictions}
    for k, qp in predictions.items():
        if k not in pred_pts and partial[k]:
            pts = np.full((len(idx),) + true_pts.shape[1:], np.nan)
            pts[partial[k]] = backbone_points(spec, np.asarray(qp, float)[idx[partial[k]]])
            pred_pts[k] = pts
    dim = true_pts.shape[1]
    fig = plt.figure(figsize=(3.6 * len(idx), 3.9), layout="constrained")
    for j, i in enumerate(idx):
        ax = _axes(fig, dim, (1, len(idx), j + 1))
        # the view is the truth's (a prediction far off is cut at its edge, and says so), so
        # that one running away does not shrink the arm to a dot
        box = _limits(ax, true_pts, spec, margin=1.6)
        left = []
        for k, pts in pred_pts.items():
            if not np.isnan(pts[j]).any():
                shown = _inside(pts[j], box) if dim == 3 else pts[j]
                if np.isnan(shown).any() or np.any((pts[j] < box[0][:, None])
                                                   | (pts[j] > box[1][:, None])):
                    left.append(NETWORK.get(k, k))
                _draw(ax, shown, color=COLORS.get(k, "C2"), style="--", lw=1.6,
                      label=NETWORK.get(k, k))
        _draw(ax, true_pts[j], color="k", label="truth", lw=1.6)  # on top: visible at t = 0
        ax.set_title(f"t = {t[i] - t[0]:.3g} s", fontsize=9)
        if left:
            where = ax.text2D if dim == 3 else ax.text
            where(0.5, -0.02 if dim == 3 else 0.02, f"{', '.join(left)}: leaves the view",
                  transform=ax.transAxes, ha="center", va="top" if dim == 3 else "bottom",
                  fontsize=7, color="0.3")
        if j == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(_with_gravity(title, spec), fontsize=10)
    path = Path(path)
    save_for_print(fig, path, dpi=dpi, pdf=pdf)  # show writes the PNG alone: no side file
    plt.close(fig)
    return path


def shape_animation(spec, t: np.ndarray, q_true: np.ndarray,
                    predictions: Mapping[str, np.ndarray], *, path: str | Path, title: str,
                    frames: int = 40, fps: int = 10, dpi: int = 80) -> Path:
    """A GIF of the true and predicted arms over the rollout (``frames`` frames, spread evenly;
    a diverged prediction disappears where it left)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    t = np.asarray(t, float)
    q_true = np.asarray(q_true, float)
    if is_draft():  # a quick run's draft: fewer frames (each is a full draw)
        frames = min(frames, 15)
    idx = np.unique(np.linspace(0, len(t) - 1, frames).round().astype(int))
    true_pts = backbone_points(spec, q_true[idx])
    preds = {}
    for k, qp in predictions.items():
        c = diverged_at(qp, q_true)
        keep = [j for j, i in enumerate(idx) if c is None or i < c]
        pts = np.full_like(true_pts, np.nan)
        if keep:
            pts[keep] = backbone_points(spec, np.asarray(qp, float)[idx[keep]])
        preds[k] = pts
    dim = true_pts.shape[1]
    fig = plt.figure(figsize=(5, 5))
    ax = _axes(fig, dim)
    every = np.concatenate([true_pts] + [p[~np.isnan(p).any(axis=(1, 2))] for p in preds.values()])
    _limits(ax, every, spec)
    title = _with_gravity(title, spec)
    line_true, = ax.plot(*true_pts[0], "k-", lw=2.2, label="truth")
    lines = {k: ax.plot(*p[0], "--", lw=1.8, color=COLORS.get(k, "C2"),
                        label=NETWORK.get(k, k))[0] for k, p in preds.items()}
    ax.legend(fontsize=7, loc="upper left")
    head = ax.set_title("", fontsize=9)

    def frame(j):
        for artist, pts in [(line_true, true_pts[j])] + [(lines[k], p[j])
                                                          for k, p in preds.items()]:
            if dim == 3:
                artist.set_data(pts[0], pts[1])
                artist.set_3d_properties(pts[2])
            else:
                artist.set_data(pts[0], pts[1])
        head.set_text(f"{title}\nt = {t[idx[j]] - t[0]:.2f} s")
        return [line_true, *lines.values(), head]

    anim = FuncAnimation(fig, frame, frames=len(idx), blit=False)
    path = Path(path)
    anim.save(path, writer=PillowWriter(fps=fps), dpi=dpi)
    plt.close(fig)
    return path
