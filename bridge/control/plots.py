"""Figures of a control comparison (matplotlib's object API on the Agg canvas, no pyplot).

Per reference ``<ref>``, in the figures folder:

* ``paths_<ref>.png``: the output's path (the tip in 3-D for a spatial arm, in the plane for a
  planar one, q's first two coordinates otherwise), reference dashed;
* ``tracking_<ref>.png``: each output component over time with the reference, and the
  tracking error ‖y - r‖ over time (log scale; × where a learned model's arm is outside the
  configurations of its training data);
* ``inputs_<ref>.png``: each input over time;
* ``solve_<ref>.png``: the solve time of each control step, with the step length (the real-time
  budget) as a line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from softpinn.bridge.control.loop import outside_mask
from softpinn.bridge.figures.arm import gravity_up_axis

__all__ = ["write_figures"]


def _save(fig: Figure, path: Path) -> None:
    FigureCanvasAgg(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=100)
    tmp.replace(path)


def _equal_3d(ax, arrays):
    """The same scale on x, y and z (a horizontal circle stays flat), around the reference
    (paths that wander more than twice its size away are cut); returns the box (lo, hi)."""
    pts = np.concatenate([a for a in arrays if len(a)])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    ref = arrays[0]
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    # the reference's box, widened to hold the other paths unless they wander far off
    span = max(float(np.max(hi - lo)), _first_extent(arrays[1:2]), 1e-3)
    lo_all = np.maximum(pts.min(axis=0), lo - 2 * span)
    hi_all = np.minimum(pts.max(axis=0), hi + 2 * span)
    mid = 0.5 * (lo_all + hi_all)
    half = 0.5 * max(float(np.max(hi_all - lo_all)), span) * 1.05
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    return mid - half, mid + half


def _first_extent(paths) -> float:
    """The largest extent of the first path (the true model's controller, the best case): a
    step reference is constant over a short run, and the view must still hold the approach."""
    if not len(paths) or not len(paths[0]):
        return 0.0
    y = np.asarray(paths[0], float)
    y = y[np.all(np.isfinite(y), axis=1)]
    return float(np.max(np.ptp(y, axis=0))) if len(y) else 0.0


def _panel_limits(ref, j, paths):
    """y-limits of output component ``j``: the reference's range with a margin of half the
    reference's largest extent, widened for paths within two extents of it (a run-away
    controller is seen leaving, in the error panel, without flattening the others)."""
    span = max(float(np.max(np.ptp(ref, axis=0))), _first_extent(paths), 1e-3)
    lo, hi = float(np.min(ref[:, j])), float(np.max(ref[:, j]))
    low, high = lo - 0.5 * span, hi + 0.5 * span
    for y in paths:
        v = y[:, j][np.isfinite(y[:, j])]
        if v.size:
            low = min(low, max(float(v.min()), lo - 2 * span))
            high = max(high, min(float(v.max()), hi + 2 * span))
    return low, high


def _colors(names):
    cmap = colormaps["tab10"]
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def write_figures(folder, spec, refs: dict, traces: dict, result: dict) -> list[str]:
    """Write the figures of every reference into ``folder``; returns their paths relative to
    ``folder``'s parent (as report.md links them)."""
    folder = Path(folder)
    comps = result["output"]["components"]
    unit = result["output"]["unit"]
    dt = result["config"]["dt"]
    written = []
    for rname, per in traces.items():
        colors = _colors(per)
        R = refs[rname]["R"][: refs[rname]["steps"]]
        r_full = np.concatenate([R[:1], R])
        t_ref = np.arange(len(r_full)) * dt
        title = f"{spec.name}, {rname} reference"

        # paths
        fig = Figure(figsize=(6.4, 5.6))
        spatial = r_full.shape[1] == 3 and spec.kind == "spatial-pcc"
        if spatial:
            ax = fig.add_subplot(projection="3d")
            lo, hi = _equal_3d(ax, [r_full] + [res["y"] for res in per.values()])
            ax.plot(*r_full.T, "k--", lw=1.5, label="reference")
            for name, res in per.items():
                y = np.array(res["y"], float)
                y[np.any((y < lo) | (y > hi), axis=1)] = np.nan  # 3-D lines are not clipped
                ax.plot(*y.T, color=colors[name], lw=1.2, label=name)
            ax.set_xlabel(f"{comps[0]} [{unit}]")
            ax.set_ylabel(f"{comps[1]} [{unit}]")
            ax.set_zlabel(f"{comps[2]} [{unit}]", labelpad=12)
            if gravity_up_axis(spec):  # a hanging arm: gravity along +z, drawn downwards
                ax.invert_zaxis()
        else:
            ax = fig.add_subplot()
            if r_full.shape[1] >= 2:
                ax.plot(r_full[:, 0], r_full[:, 1], "k--", lw=1.5, label="reference")
                for name, res in per.items():
                    ax.plot(res["y"][:, 0], res["y"][:, 1], color=colors[name], lw=1.2,
                            label=name)
                ax.set_xlabel(f"{comps[0]} [{unit}]")
                ax.set_ylabel(f"{comps[1]} [{unit}]")
                # the reference and the paths near it in view, a run-away one cut at the edge
                paths = [res["y"] for res in per.values()]
                (x0, x1), (y0, y1) = (_panel_limits(r_full, j, paths) for j in (0, 1))
                half = 0.5 * max(x1 - x0, y1 - y0)
                cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
                ax.set_xlim(cx - half, cx + half)
                ax.set_ylim(cy - half, cy + half)
                ax.set_aspect("equal", adjustable="box")
            else:
                ax.plot(t_ref, r_full[:, 0], "k--", lw=1.5, label="reference")
                for name, res in per.items():
                    ax.plot(np.arange(len(res["y"])) * dt, res["y"][:, 0], color=colors[name],
                            label=name)
                ax.set_xlabel("time [s]")
                ax.set_ylabel(f"{comps[0]} [{unit}]")
        ax.set_title(f"{title}: paths")
        ax.legend(fontsize=8)
        _save(fig, folder / f"paths_{rname}.png")
        written.append(f"figures/paths_{rname}.png")

        # outputs and error over time
        ny = r_full.shape[1]
        fig = Figure(figsize=(7.5, 2.0 * (ny + 1) + 0.6))
        axes = fig.subplots(ny + 1, 1, sharex=True)
        for j in range(ny):
            axes[j].plot(t_ref, r_full[:, j], "k--", lw=1.5, label="reference")
            for name, res in per.items():
                axes[j].plot(np.arange(len(res["y"])) * dt, res["y"][:, j], color=colors[name],
                             lw=1.1, label=name)
            axes[j].set_ylabel(f"{comps[j]} [{unit}]")
            axes[j].set_ylim(*_panel_limits(r_full, j, [res["y"] for res in per.values()]))
        axes[0].legend(fontsize=8, ncol=2)
        marked = False
        for name, res in per.items():
            e = np.linalg.norm(res["y"] - res["r"], axis=1)
            t_e = np.arange(len(e)) * dt
            axes[-1].semilogy(t_e[1:], np.maximum(e[1:], 1e-12), color=colors[name], lw=1.1,
                              label=name)
            q_range = result["controllers"].get(name, {}).get("q_range")
            if q_range:  # where a learned model's arm is outside its training data
                away = outside_mask(res["x"], q_range).any(axis=1)
                away[0] = False
                if away.any():
                    axes[-1].semilogy(t_e[away], np.maximum(e[away], 1e-12), "x",
                                      color=colors[name], ms=3.5, mew=0.8,
                                      label=None if marked else
                                      "outside its training data's q")
                    marked = True
        if marked:
            axes[-1].legend(fontsize=7, loc="best")
        axes[-1].set_ylabel(f"‖y - r‖ [{unit}]")
        axes[-1].set_xlabel("time [s]")
        axes[0].set_title(f"{title}: outputs and tracking error")
        fig.tight_layout()
        _save(fig, folder / f"tracking_{rname}.png")
        written.append(f"figures/tracking_{rname}.png")

        # inputs
        m = spec.m
        fig = Figure(figsize=(7.5, 1.9 * m + 0.8))
        axes = np.atleast_1d(fig.subplots(m, 1, sharex=True))
        for j in range(m):
            for name, res in per.items():
                axes[j].step(np.arange(len(res["u"])) * dt, res["u"][:, j], where="post",
                             color=colors[name], lw=1.0, label=name)
            axes[j].set_ylabel(f"u{j + 1} (input units)")
        axes[0].legend(fontsize=8, ncol=2)
        axes[-1].set_xlabel("time [s]")
        axes[0].set_title(f"{title}: inputs")
        fig.tight_layout()
        _save(fig, folder / f"inputs_{rname}.png")
        written.append(f"figures/inputs_{rname}.png")

        # solve times
        fig = Figure(figsize=(7.5, 3.6))
        ax = fig.add_subplot()
        for name, res in per.items():
            s = np.asarray(res["seconds"]) * 1e3
            ax.semilogy(np.arange(len(s)) * dt, np.maximum(s, 1e-3), color=colors[name],
                        lw=1.0, label=name)
        ax.axhline(dt * 1e3, color="k", ls=":", lw=1.2,
                   label=f"control step {dt * 1e3:g} ms")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("solve time per step [ms]")
        ax.set_title(f"{title}: solve times ({result['config']['solver']}, horizon "
                     f"{result['config']['horizon']})")
        ax.legend(fontsize=8, ncol=2)
        fig.tight_layout()
        _save(fig, folder / f"solve_{rname}.png")
        written.append(f"figures/solve_{rname}.png")
    return written
