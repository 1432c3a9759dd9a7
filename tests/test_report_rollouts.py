"""Rollout figures survive a diverged prediction (issue 15: task4 --quick crashed in matplotlib's
log axis on an infinite error) and say where it diverged; coordinates carry their units."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.figures.rollouts import (
    diverged_at,
    finite_percentile,
    finite_points,
    rollout_figure,
)
from softpinn.learn.plots import coordinate_unit


def _truth(n=3, samples=200):
    t = np.linspace(0.0, 2.0, samples)
    return t, np.stack([np.sin((i + 1) * t) for i in range(n)], axis=1)


def test_finite_percentile_is_nanpercentile_over_the_finite_entries():
    """The shading's percentiles: numpy's nanpercentile (non-finite entries as NaN) column by
    column, to rounding; a column with no finite entry gives NaN, one with one entry that."""
    rng = np.random.default_rng(0)
    a = rng.lognormal(size=(9, 300))
    a[rng.random(a.shape) < 0.3] = np.nan
    a[rng.random(a.shape) < 0.1] = np.inf
    a[:, 7] = np.inf  # every trajectory diverged here
    a[1:, 8] = np.nan  # one left
    a[:, 9] = 2.0  # ties
    for p in (0, 10, 50, 90, 100):
        got = finite_percentile(a, p)
        with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
            want = np.nanpercentile(np.where(np.isfinite(a), a, np.nan), p, axis=0)
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=0)
        assert np.isnan(got[7]) and got[8] == a[0, 8] and got[9] == 2.0


def test_diverged_at_finds_non_finite_and_runaway_samples():
    t, q = _truth()
    assert diverged_at(q + 1e-3, q) is None
    bad = q.copy()
    bad[50:] = np.inf
    assert diverged_at(bad, q) == 50
    bad = q.copy()
    bad[70, 1] = np.nan
    assert diverged_at(bad, q) == 70
    bad = q.copy()
    bad[120:] = 1e9  # finite, but a billion times the truth's range away
    assert diverged_at(bad, q) == 120


@pytest.mark.parametrize("blowup", [np.inf, np.nan, 1e300])
def test_figure_with_a_diverged_model_is_written(tmp_path, blowup):
    t, q = _truth()
    bad = q + 0.01
    bad[80:] = blowup
    path = rollout_figure(t, q, {"lagrangian": q + 1e-3, "hamiltonian": bad, "blackbox": q * 0.9},
                          names=["dx1", "dy1", "dL1"], units=["m", "m", "m"],
                          title="test", path=tmp_path / "r.png")
    assert path.is_file() and path.stat().st_size > 10_000


def test_figure_when_every_model_diverged_at_once(tmp_path):
    t, q = _truth(n=2)
    path = rollout_figure(t, q, {"lagrangian": np.full_like(q, np.inf)}, names=["theta1", "dL1"],
                          units=["rad", "m"], title="all gone", path=tmp_path / "r.png")
    assert path.is_file()


def test_units_and_finite_points():
    assert coordinate_unit("theta2", "planar-pcc") == "rad"
    assert coordinate_unit("dL1", "planar-pcc") == "m"
    assert coordinate_unit("dx2", "spatial-pcc") == "m"
    assert coordinate_unit("q1", "double-pendulum") == "rad"
    assert coordinate_unit("q1", "mass-spring-damper") == "m"
    x, y, e, lost = finite_points([10, 50, 100], [1e-3, np.inf, 2e-3], [1e-4, np.nan, np.inf])
    assert x.tolist() == [10, 100] and lost.tolist() == [50] and e.tolist() == [1e-4, 0.0]


def test_error_against_horizon_with_diverged_trajectories(tmp_path):
    from softpinn.bridge.figures.rollouts import horizon_figure

    t = np.linspace(0.0, 2.0, 100)
    good = 1e-4 * np.exp(t)[None, :] * np.array([[1.0], [2.0], [3.0]])
    bad = good.copy()
    bad[1, 60:] = np.inf
    path = horizon_figure({"lagrangian": (t, good), "hamiltonian": (t, bad)}, title="h",
                          path=tmp_path / "h.png")
    assert path.is_file() and path.stat().st_size > 10_000


def test_rollout_figure_draws_the_inputs(tmp_path, monkeypatch):
    """Given u (T, m) the figure has one panel more than without: the inputs, one line per
    input with the values of u against t, labelled u1 ... um."""
    from softpinn.bridge.figures import rollouts

    drawn = []  # per figure: (y-label, legend labels, lines as (x, y)) of every axes
    original = rollouts.save_for_print

    def spy(fig, path, **kw):
        drawn.append([(ax.get_ylabel(), [line.get_label() for line in ax.get_lines()],
                       [(np.asarray(line.get_xdata()), np.asarray(line.get_ydata()))
                        for line in ax.get_lines()]) for ax in fig.axes])
        return original(fig, path, **kw)

    monkeypatch.setattr(rollouts, "save_for_print", spy)
    t, q = _truth(n=2)
    u = np.stack([np.cos(t), np.sin(t)], axis=1)
    kw = dict(names=["theta1", "dL1"], units=["rad", "m"], title="u")
    path = rollout_figure(t, q, {"lagrangian": q}, path=tmp_path / "u.png", u=u, **kw)
    assert path.is_file()
    rollout_figure(t, q, {"lagrangian": q}, path=tmp_path / "no-u.png", **kw)
    with_u, without_u = drawn

    def is_inputs(lines):
        return len(lines) == u.shape[1] and all(
            np.array_equal(x, t) and np.array_equal(y, u[:, j]) for j, (x, y) in enumerate(lines))

    panels = [(ylabel, labels) for ylabel, labels, lines in with_u if is_inputs(lines)]
    assert panels == [("inputs u", ["u1", "u2"])]
    assert len(with_u) == len(without_u) + 1
    assert not any(is_inputs(lines) for _, _, lines in without_u)


def test_rollout_figure_shades_every_test_trajectory_behind_the_one_drawn(tmp_path):
    import matplotlib.pyplot as plt

    t, q = _truth(n=2)
    pred = q + 1e-3
    errors = 1e-3 * np.array([[1.0], [2.0], [4.0], [8.0], [16.0]]) * np.ones((5, t.size))
    errors[4, t.size // 2:] = np.inf  # one test trajectory diverged half way: no inf drawn
    drawn = []
    original = plt.Axes.fill_between

    def spy(self, x, y1, y2, **kw):
        drawn.append((np.asarray(x), np.asarray(y1), np.asarray(y2)))
        return original(self, x, y1, y2, **kw)

    plt.Axes.fill_between = spy
    try:
        path = rollout_figure(t, q, {"lagrangian": pred}, names=["theta1", "dL1"],
                              units=["rad", "m"], title="band", path=tmp_path / "b.png",
                              bands={"lagrangian": (t - t[0], errors)})
    finally:
        plt.Axes.fill_between = original
    assert path.is_file() and path.with_suffix(".pdf").is_file()
    (x, lo, hi), = drawn
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)
    # 10-90 % of 1, 2, 4, 8, 16 (e-3)
    assert lo[0] == pytest.approx(1.4e-3) and hi[0] == pytest.approx(1.28e-2)
    # fewer than five trajectories: no band (it would say nothing)
    drawn.clear()
    plt.Axes.fill_between = spy
    try:
        rollout_figure(t, q, {"lagrangian": pred}, names=["theta1", "dL1"], units=["rad", "m"],
                       title="few", path=tmp_path / "f.png",
                       bands={"lagrangian": (t - t[0], errors[:3])})
    finally:
        plt.Axes.fill_between = original
    assert drawn == []


def test_a_quick_run_draws_drafts_and_a_full_run_print_copies(tmp_path):
    """Inside draft_figures (quick runs) a figure is one PNG at screen resolution and no PDF;
    outside, a 300 dpi PNG and its vector PDF."""
    from PIL import Image

    from softpinn.bridge.figures.figsave import DPI, DRAFT_DPI, draft_figures, is_draft

    t, q = _truth(n=2)
    kw = dict(names=["theta1", "dL1"], units=["rad", "m"], title="drafts")
    with draft_figures(True):
        assert is_draft()
        with draft_figures(False):  # a full block inside a draft stays a draft
            assert is_draft()
        draft = rollout_figure(t, q, {"lagrangian": q + 1e-3}, path=tmp_path / "d.png", **kw)
    assert not is_draft()
    full = rollout_figure(t, q, {"lagrangian": q + 1e-3}, path=tmp_path / "f.png", **kw)
    assert not draft.with_suffix(".pdf").exists() and full.with_suffix(".pdf").is_file()
    dpi = {}
    for p in (draft, full):
        with Image.open(p) as image:
            dpi[p] = image.info["dpi"][0]
    assert dpi[draft] == pytest.approx(DRAFT_DPI, abs=1) and dpi[full] == pytest.approx(DPI, abs=1)


def test_a_figure_larger_than_a_page_is_written_within_the_pixel_cap(tmp_path):
    """300 dpi for a figure of a page's size; one too large for it (task 5's 36 panels of
    P(q)) at the resolution that fills MAX_PIXELS, never below a draft's."""
    from matplotlib.figure import Figure
    from PIL import Image

    from softpinn.bridge.figures.figsave import DPI, DRAFT_DPI, MAX_PIXELS, figure_dpi

    assert figure_dpi(300, Figure(figsize=(7.0, 5.0))) == DPI
    big = Figure(figsize=(16.6, 13.9))
    dpi = figure_dpi(300, big)
    assert DRAFT_DPI < dpi < DPI and 16.6 * 13.9 * dpi**2 <= MAX_PIXELS
    assert figure_dpi(300, Figure(figsize=(100.0, 100.0))) == DRAFT_DPI
    big.add_subplot().plot([0, 1], [0, 1])
    big.savefig(tmp_path / "big.png", dpi=dpi)
    with Image.open(tmp_path / "big.png") as image:
        assert image.size[0] * image.size[1] <= MAX_PIXELS
