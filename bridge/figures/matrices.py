"""Plots of the matrix-equivalence analysis (matplotlib's object API with the Agg canvas; no
pyplot, so no global state):

* :func:`plot_entries_scatter`: every entry of each true matrix against the same entry of the
  (transformed) learned one, over all q, with the identity line: points on the line mean
  ``P X^ = X`` (Tables I, II, V-IX, as pictures);
* :func:`plot_transform_entries`: the entries of P(q) over the sampled q, one panel per entry,
  one series per transform (pointwise P(q) beside a smooth fit, a constant P or I / alpha).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from softpinn.bridge.analysis.forces import FRAME_LABELS, TERMS
from softpinn.bridge.analysis.transforms import as_stack
from softpinn.bridge.figures.figsave import figure_dpi
from softpinn.bridge.figures.tables import percent_text
from softpinn.errors import UserError

_TITLES = {"M": "M(q)", "M_inv": "M⁻¹(q)", "D": "D(q)", "G": "G(q)", "A": "A(q)"}


def _save(fig: Figure, path: str | Path | None) -> Figure:
    FigureCanvasAgg(fig)
    if path is not None:
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.stem + ".tmp" + p.suffix)
        fig.savefig(tmp, dpi=figure_dpi(300, fig))  # readable in print (a draft on quick runs)
        tmp.replace(p)
    return fig


def plot_entries_scatter(
    true,
    learned,
    result=None,
    *,
    matrices: Sequence[str] = ("M", "D", "G", "A"),
    path: str | Path | None = None,
    title: str = "",
) -> Figure:
    """Scatter of true vs learned entries per matrix, with the identity line.

    ``result``: ``None`` (learned as it is), one transform result
    (:class:`bridge.transforms.TransformResult`: the learned matrices are mapped first,
    ``P X^``) or a dict of them (one row of panels per transform). ``M_inv`` is always compared
    as it is. Saved to ``path`` (PNG, PDF, SVG by suffix) when given; the figure is returned.
    """
    true, learned = as_stack(true, "true"), as_stack(learned, "learned")
    keys = [k for k in matrices if true.has(k) and learned.has(k) and true.block(k).size > 0]
    if not keys:
        raise UserError(
            f"matrices: none of {list(matrices)} is given on both sides "
            f"(true {list(true.present)}, learned {list(learned.present)})"
        )
    if isinstance(result, Mapping):
        rows = list(result.items())
        if not rows:
            raise UserError("result: expected at least one transform result")
    else:
        rows = [(getattr(result, "name", None), result)]
    fig = Figure(figsize=(3.0 * len(keys), 3.0 * len(rows) + 0.5), layout="constrained")
    axes = fig.subplots(len(rows), len(keys), squeeze=False)
    for (name, res), row in zip(rows, axes, strict=True):
        for ax, k in zip(row, keys, strict=True):
            x = true.block(k)
            y = learned.block(k)
            mapped = res is not None and k != "M_inv"
            if mapped:
                y = res.P @ y
            x, y = x.ravel(), y.ravel()
            ok = np.isfinite(y)
            ax.scatter(x[ok], y[ok], s=8, alpha=0.6)
            lo = float(min(x.min(), y[ok].min() if ok.any() else x.min()))
            hi = float(max(x.max(), y[ok].max() if ok.any() else x.max()))
            pad = 0.05 * (hi - lo or 1.0)
            ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "k--", lw=0.8)
            ax.set_title(_TITLES.get(k, k) if name is None else f"{_TITLES.get(k, k)}, {name}")
            ax.set_xlabel("true")
            ax.set_ylabel("P · learned" if mapped else "learned")
    fig.suptitle(title or "true vs learned entries (dashed: identity)")
    return _save(fig, path)


def plot_transform_entries(
    q: np.ndarray,
    results: Mapping[str, object],
    *,
    coordinate: int | None = None,
    path: str | Path | None = None,
    title: str = "",
    coordinate_label: str | None = None,
    entries: Sequence[tuple[int, int]] | None = None,
) -> Figure:
    """Entries P_ij over the sampled q, one panel per entry and one series per transform.

    The x axis is the sample index, or ``q[:, coordinate]`` (points sorted by it; labelled
    ``coordinate_label``, e.g. 'dx1 [m]', else q1, q2, ... as the entries P[1,1] count). For a
    ``smooth`` result the held-out q are drawn as open markers. ``entries``: the (i, j) to draw
    (0-based), in a grid of about square shape, the title saying how many of the n² are shown
    (a large arm's: :func:`bridge.figures.large_arms.panel_entries`); None: all of them, an
    n x n grid.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise UserError(f"q: expected shape (N, n), got {q.shape}")
    if not results:
        raise UserError("results: expected at least one transform result")
    N, n = q.shape
    for name, r in results.items():
        if r.P.shape != (N, n, n):
            raise UserError(f"results[{name!r}].P: expected shape ({N}, {n}, {n}), got {r.P.shape}")
    if coordinate is not None and not (0 <= coordinate < n):
        raise UserError(f"coordinate: expected an index in [0, {n}), got {coordinate}")
    if coordinate is None:
        x, order, xlabel = np.arange(N), np.arange(N), "sample"
    else:
        order = np.argsort(q[:, coordinate], kind="stable")
        x, xlabel = q[order, coordinate], coordinate_label or f"q{coordinate + 1}"
    if entries is None:
        rows, cols, shown = n, n, [(i, j) for i in range(n) for j in range(n)]
    else:
        shown = [(int(i), int(j)) for i, j in entries]
        if not shown or any(not (0 <= i < n and 0 <= j < n) for i, j in shown):
            raise UserError(f"entries: expected (i, j) pairs in [0, {n}), got {list(entries)}")
        cols = int(np.ceil(np.sqrt(len(shown))))
        rows = -(-len(shown) // cols)
    fig = Figure(figsize=(2.6 * cols + 1, 2.2 * rows + 0.7), layout="constrained")
    grid = fig.subplots(rows, cols, squeeze=False, sharex=True)
    axes = {e: grid[k // cols, k % cols] for k, e in enumerate(shown)}
    for k in range(len(shown), rows * cols):  # the grid's unused corner
        grid[k // cols, k % cols].set_visible(False)
    for name, r in results.items():
        P = r.P[order]
        train = getattr(r, "params", {}).get("train")
        for (i, j), ax in axes.items():
            # points, not lines: the other coordinates vary between neighbouring samples
            (line,) = ax.plot(x, P[:, i, j], linestyle="none", marker=".", ms=4, label=name)
            if train is not None:
                held = ~np.asarray(train)[order]
                ax.plot(x[held], P[held, i, j], "o", mfc="none", color=line.get_color())
    for k, ((i, j), ax) in enumerate(axes.items()):
        ax.set_title(f"P[{i + 1},{j + 1}]", fontsize="small")
        if k % cols == 0:
            ax.set_ylabel("entry of P(q)")
        if k + cols >= len(shown):  # the lowest panel of its column
            ax.set_xlabel(xlabel)
            ax.xaxis.set_tick_params(labelbottom=True)
    axes[shown[0]].legend(fontsize="x-small")
    what = "" if entries is None else f", {len(shown)} of its {n * n} entries"
    fig.suptitle(title or f"transform P(q) over the sampled q{what} (open markers: held out)")
    return _save(fig, path)


#: How each matrix is labelled in the sweeps figure.
_SWEEP_LABEL = {"M": "M(q)", "M_inv": "M⁻¹(q)", "D": "D(q)", "G": "G(q)", "A": "A(q)"}
#: The units of the matrices' entries where every coordinate has the same unit.
_SWEEP_UNITS = {"m": {"M": "kg", "M_inv": "1/kg", "D": "N s/m", "G": "N"},
                "rad": {"M": "kg m²", "M_inv": "1/(kg m²)", "D": "N m s/rad", "G": "N m"}}


def _coordinate_unit_of(name: str) -> str | None:
    """'m' of a sweep's axis name 'dL1 [m]' (None without one)."""
    return name.rsplit(" [", 1)[1].rstrip("]") if name.endswith("]") and " [" in name else None


def _sweep_entries(key: str, shape: tuple[int, ...]) -> list[tuple[int, ...]]:
    """The entries of one matrix a sweep draws: every entry of G; the diagonal of M, M⁻¹, D
    and, up to n = 3, the upper off-diagonal entries too; A whole up to 6 entries, else its
    leading diagonal."""
    if key == "G":
        return [(i,) for i in range(shape[0])]
    rows, cols = shape
    if key == "A":
        if rows * cols <= 6:
            return [(i, j) for i in range(rows) for j in range(cols)]
        return [(i, i) for i in range(min(rows, cols))]
    upper = [(i, j) for i in range(rows) for j in range(i + 1, cols)] if rows <= 3 else []
    return [(i, i) for i in range(rows)] + upper


def plot_sweeps(sweeps, *, path: str | Path | None = None, title: str = "") -> Figure:
    """True (solid) against learned (dashed, same colour) entries of M or M⁻¹, D, G and A
    along each sweep of :class:`bridge.analysis.sweeps.Sweeps`: a row per matrix, a column per
    swept coordinate, the entries named in a legend right of each row. Matrices that are zero
    on both sides (no damping, no inputs) are left out."""
    cols = list(sweeps.sweeps)
    if not cols:
        raise UserError("sweeps: nothing to draw")
    first = cols[0]
    keys = [k for k in ("M", "M_inv", "D", "G", "A")
            if first.true.has(k) and first.learned.has(k) and np.asarray(
                getattr(first.true, k)).size
            and any(np.any(getattr(s.true, k)) or np.any(getattr(s.learned, k)) for s in cols)]
    if "M" in keys and "M_inv" in keys:  # one mass-like matrix: the one the network learns
        keys.remove("M" if sweeps.mass_key == "M_inv" else "M_inv")
    if not keys:
        raise UserError("sweeps: no matrix present on both sides")
    fig = Figure(figsize=(3.0 * len(cols) + 1.6, 2.1 * len(keys) + 0.8), layout="constrained")
    axes = fig.subplots(len(keys), len(cols), squeeze=False)
    units = {_coordinate_unit_of(sw.name) for sw in cols}
    n = np.asarray(getattr(first.true, keys[0])).shape[1]
    unit = units.pop() if len(units) == 1 and len(cols) == n else None  # all alike: known
    for r, key in enumerate(keys):
        for c, sw in enumerate(cols):
            ax = axes[r, c]
            x = sw.values
            true, learned = np.asarray(getattr(sw.true, key)), np.asarray(getattr(sw.learned, key))
            entries = _sweep_entries(key, true.shape[1:])
            for e, idx in enumerate(entries):
                color = f"C{e % 10}"
                name = f"{key}[{','.join(str(i + 1) for i in idx)}]"
                # the earlier entries wider: a true entry equal to a later one shows beneath it
                wide = 1.3 + 1.2 * (len(entries) - 1 - e) / max(len(entries) - 1, 1)
                ax.plot(x, true[(slice(None), *idx)], "-", color=color, lw=wide, label=name,
                        zorder=2 + e)
                ax.plot(x, learned[(slice(None), *idx)], "--", color=color, lw=1.4,
                        zorder=2 + len(entries) + e)
            ax.grid(alpha=0.3)
            if c == 0:
                what = _SWEEP_UNITS.get(unit, {}).get(key)
                ax.set_ylabel(_SWEEP_LABEL.get(key, key) + (f" [{what}]" if what else ""))
            if r == len(keys) - 1:
                ax.set_xlabel(sw.name)
            if r == 0:
                others = "others at their median"
                ax.set_title(f"sweep of {sw.name.split(' [')[0]} ({others})", fontsize="small")
        axes[r, -1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize="x-small",
                           frameon=False)
    how = ("learned as it is" if sweeps.transform == "direct"
           else f"learned times c = 1/α = {sweeps.scale:.3g}")
    fig.suptitle(title or f"true (solid) against {how} (dashed)")
    return _save(fig, path)


def plot_forces(forces, *, path: str | Path | None = None, title: str = "") -> Figure:
    """True against learned force terms along the data (:class:`bridge.forces.ForceComparison`),
    one panel per term that is not zero, with the identity line; with inputs, a last panel of
    the learned A u's error against G's, per component: points on the identity are errors that
    cancel in the net force A u − G − D q̇. In the acceleration frame the same for M⁻¹ times
    each term."""

    terms = getattr(forces, "terms", None)
    if not terms:
        raise UserError("forces: no per-sample terms to plot (compare_forces makes them)")
    frame = getattr(forces, "frame", "force")
    labels = FRAME_LABELS[frame]
    keys = [k for k in (*TERMS, "qdd") if k in terms and np.any(terms[k][0] != 0)]
    pair = forces.error.get("A_u") is not None and forces.error.get("G") is not None
    fig = Figure(figsize=(3.0 * (len(keys) + pair), 3.4))
    axes = fig.subplots(1, len(keys) + pair, squeeze=False)[0]
    for ax, k in zip(axes, keys, strict=False):
        x, y = terms[k][0].ravel(), terms[k][1].ravel()
        _identity_scatter(ax, x, y)
        err = forces.error[k]
        ax.set_title(labels[k] + ("" if err is None else f"  (error {percent_text(err)})"))
        ax.set_xlabel("true")
        ax.set_ylabel("learned" if forces.scale == 1 else "learned / α")
    if pair:
        ax = axes[-1]
        eg = (terms["G"][1] - terms["G"][0]).ravel()
        ea = (terms["A_u"][1] - terms["A_u"][0]).ravel()
        _identity_scatter(ax, eg, ea)
        ax.set_title(f"errors (cancellation {forces.cancellation:.2g})")
        ax.set_xlabel(f"error of {labels['G']}")
        ax.set_ylabel(f"error of {labels['A_u']}")
    fig.suptitle(title or f"{frame} terms along {forces.samples} data samples (dashed: identity)")
    fig.tight_layout()
    return _save(fig, path)


def _identity_scatter(ax, x, y) -> None:
    ax.scatter(x, y, s=4, alpha=0.4)
    lo, hi = float(min(x.min(), y.min())), float(max(x.max(), y.max()))
    pad = 0.05 * (hi - lo or 1.0)
    ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "k--", lw=0.8)
