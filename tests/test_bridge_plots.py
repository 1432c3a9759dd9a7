"""bridge.plots: the scatter of true vs transformed learned entries and P(q) over q."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.analysis.transforms import fit_alpha, fit_pointwise, fit_smooth
from softpinn.bridge.figures.matrices import plot_entries_scatter, plot_transform_entries
from softpinn.errors import UserError


def stacks(N=12, n=2, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1, 1, (N, n))
    true = {
        "M": np.eye(n) * 2 + 0.1 * q[:, :, None] * q[:, None, :],
        "D": np.broadcast_to(0.3 * np.eye(n), (N, n, n)).copy(),
        "G": np.sin(q),
        "A": np.broadcast_to(np.eye(n)[:, :1], (N, n, 1)).copy(),
    }
    P = np.eye(n) * 1.5 + 0.2 * q[:, :, None] * np.ones((1, 1, n))
    Pinv = np.linalg.inv(P)
    learned = {k: Pinv @ v for k, v in true.items() if k != "G"}
    learned["G"] = (Pinv @ true["G"][:, :, None])[:, :, 0]
    return q, true, learned


def test_scatter_points_lie_on_identity_after_transform(tmp_path):
    q, true, learned = stacks()
    res = fit_pointwise(true, learned, q)
    path = tmp_path / "plots" / "scatter.png"
    fig = plot_entries_scatter(true, learned, res, path=path)
    assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(path.parent.glob("*.tmp*"))
    assert [ax.get_title() for ax in fig.axes] == [
        "M(q), pointwise",
        "D(q), pointwise",
        "G(q), pointwise",
        "A(q), pointwise",
    ]
    pts = fig.axes[0].collections[0].get_offsets()
    assert pts.shape == (12 * 4, 2)
    np.testing.assert_allclose(pts[:, 0], true["M"].ravel())
    np.testing.assert_allclose(pts[:, 1], pts[:, 0], atol=1e-12)  # on the identity line
    # without the transform the learned entries are off the line
    raw = plot_entries_scatter(true, learned).axes[2].collections[0].get_offsets()
    np.testing.assert_allclose(raw[:, 1], learned["G"].ravel())
    assert np.max(np.abs(raw[:, 1] - raw[:, 0])) > 0.1


def test_scatter_one_row_per_transform():
    q, true, learned = stacks()
    results = {"direct": None, "alpha": fit_alpha(true, learned, q)}
    fig = plot_entries_scatter(true, learned, results, matrices=("M", "G"))
    assert [ax.get_title() for ax in fig.axes] == ["M(q), direct", "G(q), direct",
                                                   "M(q), alpha", "G(q), alpha"]  # fmt: skip
    np.testing.assert_allclose(fig.axes[1].collections[0].get_offsets()[:, 1], learned["G"].ravel())
    P = results["alpha"].P
    ref = (P @ learned["G"][:, :, None]).ravel()
    np.testing.assert_allclose(fig.axes[3].collections[0].get_offsets()[:, 1], ref)


def test_scatter_hamiltonian_compares_M_inv_directly():
    q, true, learned = stacks(N=5)
    learned = dict(true)
    learned["M_inv"] = np.linalg.inv(learned.pop("M"))
    fig = plot_entries_scatter(true, learned, matrices=("M_inv", "D"))
    pts = fig.axes[0].collections[0].get_offsets()
    np.testing.assert_allclose(pts[:, 1], np.linalg.inv(true["M"]).ravel(), rtol=1e-12)


def test_transform_entries_panels_and_series(tmp_path):
    q, true, learned = stacks(N=20)
    results = {
        "pointwise": fit_pointwise(true, learned, q),
        "smooth": fit_smooth(true, learned, q, degree=1, heldout=0.25),
        "alpha": fit_alpha(true, learned, q),
    }
    path = tmp_path / "P.svg"
    fig = plot_transform_entries(q, results, coordinate=1, path=path)
    assert path.is_file() and b"<svg" in path.read_bytes()[:400]
    axes = [ax for ax in fig.axes if ax.get_title().startswith("P[")]
    assert [ax.get_title() for ax in axes] == ["P[1,1]", "P[1,2]", "P[2,1]", "P[2,2]"]
    order = np.argsort(q[:, 1], kind="stable")
    lines = axes[1].get_lines()  # P[1,2]: pointwise, smooth, smooth held-out, alpha
    assert len(lines) == 4
    np.testing.assert_allclose(lines[0].get_xdata(), q[order, 1])
    np.testing.assert_allclose(lines[0].get_ydata(), results["pointwise"].P[order, 0, 1])
    assert len(lines[2].get_xdata()) == 5  # held-out q of the smooth fit
    np.testing.assert_allclose(lines[3].get_ydata(), 0.0)  # I / alpha has no off-diagonal
    # points, no lines, and visible ones (a colour of "none" once drew an empty figure)
    from matplotlib.colors import to_rgba

    for line in lines:
        assert line.get_linestyle() == "None" and line.get_marker() in (".", "o")
        assert to_rgba(line.get_markeredgecolor())[3] > 0


def test_plot_bad_input():
    q, true, learned = stacks(N=4)
    res = fit_pointwise(true, learned, q)
    with pytest.raises(UserError, match=r"coordinate: expected an index in \[0, 2\), got 5"):
        plot_transform_entries(q, {"pointwise": res}, coordinate=5)
    with pytest.raises(UserError, match=r"P: expected shape \(3, 2, 2\)"):
        plot_transform_entries(q[:3], {"pointwise": res})
    with pytest.raises(UserError, match="none of"):
        plot_entries_scatter(true, {"M_inv": np.linalg.inv(learned["M"])}, matrices=("G",))
