"""The arm itself (issue 19): the backbone of eqs. 13-14 and 27, drawn and animated."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.figures.arm import draw_configurations, shape_animation, shape_figure
from softpinn.errors import UserError
from softpinn.symbolic.derivation._shape import backbone_points
from softpinn.symbolic.spec._spec import load_spec


@pytest.mark.parametrize("task", ["task3", "task4", "task5"])
def test_a_straight_arm_is_a_vertical_line_of_the_rest_length(task):
    spec = load_spec(task)
    pts = backbone_points(spec, np.zeros(spec.n), points_per_segment=5)
    length = sum(s.length for s in spec.segments)
    up = pts[-1]  # planar: y is along the arm at rest; spatial: z
    assert np.allclose(pts[:-1], 0.0, atol=1e-15)
    assert np.allclose(up, np.linspace(0.0, length, pts.shape[1]), atol=1e-14)


def test_a_planar_arc_has_its_length_and_curvature():
    spec = load_spec("task3")
    theta, dL = 1.2, 0.05
    pts = backbone_points(spec, [theta, dL], points_per_segment=400)
    L = spec.segments[0].length + dL
    arc = np.sum(np.linalg.norm(np.diff(pts, axis=1), axis=0))
    assert arc == pytest.approx(L, rel=1e-5)
    # the tip of a constant-curvature arc: L / theta (1 - cos theta, sin theta)
    assert np.allclose(pts[:, -1], L / theta * np.array([1 - np.cos(theta), np.sin(theta)]))


def test_spatial_backbone_points_batch_and_errors():
    spec = load_spec("task5")
    q = np.random.default_rng(0).normal(scale=0.02, size=(4, spec.n))
    many = backbone_points(spec, q, points_per_segment=3)
    assert many.shape == (4, 3, 7)
    assert np.allclose(many[2], backbone_points(spec, q[2], points_per_segment=3))
    with pytest.raises(UserError, match="expected 6 numbers"):
        backbone_points(spec, np.zeros(5))
    with pytest.raises(UserError, match="NaN"):
        backbone_points(spec, np.full(6, np.nan))
    with pytest.raises(UserError, match="not a PCC arm"):
        backbone_points(load_spec("task2"), np.zeros(2))


def test_figures_are_written_also_when_a_prediction_diverged(tmp_path):
    spec = load_spec("task4")
    t = np.linspace(0.0, 1.0, 50)
    q = np.stack([0.01 * np.sin(t), 0.01 * np.cos(t), 0.001 * t], axis=1)
    bad = q.copy()
    bad[20:] = np.inf
    png = shape_figure(spec, t, q, {"lagrangian": q * 0.9, "hamiltonian": bad},
                       path=tmp_path / "shape.png", title="t")
    gif = shape_animation(spec, t, q, {"lagrangian": q * 0.9, "hamiltonian": bad},
                          path=tmp_path / "shape.gif", title="t", frames=5)
    assert png.stat().st_size > 10_000 and gif.read_bytes()[:4] == b"GIF8"
    assert png.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"  # the vector copy for print
    one = draw_configurations(load_spec("task3"), [[0.0, 0.0], [1.0, 0.0]],
                              path=tmp_path / "show.png")
    assert one.is_file()


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: "), err
    return err[0]


def test_show_cli_draws_configurations_and_trajectories(tmp_path, capsys):
    from softpinn.bridge.cli import main

    out = tmp_path / "arm.png"
    assert main(["show", "task3", "--q", "0", "0", "1.0", "0.02", "--out", str(out)]) == 0
    assert out.is_file() and "2 configuration(s)" in capsys.readouterr().out
    assert main(["show", "task3", "--q", "0", "0", "--out", str(out)]) == 2
    assert "exists" in _err(capsys)
    assert main(["show", "task3", "--q", "0", "--out", str(tmp_path / "b.png")]) == 2
    assert "multiple of n = 2" in _err(capsys)
    assert main(["show", "task2", "--q", "0", "0", "--out", str(tmp_path / "c.png")]) == 2
    assert "not a PCC arm" in _err(capsys)
    assert main(["show", "task3", "--out", str(tmp_path / "d.png")]) == 2
    assert "--q" in _err(capsys)
    assert main(["show", "task3", "--q", "0", "0", "--out", str(tmp_path / "e.gif")]) == 2
    assert "expected a .png" in _err(capsys)
    data = tmp_path / "d.npz"
    assert main(["simulate", "task3", "--trajectories", "1", "--duration", "0.5", "--out",
                 str(data)]) == 0
    capsys.readouterr()
    gif = tmp_path / "traj.gif"
    assert main(["show", "task3", "--data", str(data), "--out", str(gif)]) == 0
    assert gif.read_bytes()[:4] == b"GIF8"
    capsys.readouterr()
    assert main(["show", "task3", "--data", str(data), "--trajectory", "7", "--out",
                 str(tmp_path / "x.gif")]) == 2
    assert "not in" in _err(capsys)
    assert main(["show", "task4", "--data", str(data), "--out", str(tmp_path / "y.gif")]) == 2
    assert "n = 2" in _err(capsys)
    # a PNG of the trajectory is the PNG alone: a PDF of the user's beside it is untouched
    (tmp_path / "fig.pdf").write_text("my paper figure")
    assert main(["show", "task3", "--data", str(data), "--out", str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.pdf").read_text() == "my paper figure"
    capsys.readouterr()
    # a file that is no data set: one line
    (tmp_path / "junk.npz").write_text("junk")
    assert main(["show", "task3", "--data", str(tmp_path / "junk.npz"), "--out",
                 str(tmp_path / "j.gif")]) == 2
    assert "junk.npz: cannot be read as a data set" in _err(capsys)
