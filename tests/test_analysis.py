"""bridge.analysis: true (CasADi) and learned (JAX) models evaluated at the same q, every fit
run, and the report written."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.bridge.analysis import AnalysisResult, analysis_q, analyze, sample_q
from softpinn.bridge.figures.analysis import summary_numbers, write_report
from softpinn.bridge.figures.tables import read_csv
from softpinn.errors import UserError
from softpinn.learn._models import ModelConfig, make_model
from softpinn.symbolic.model._true_model import TrueModel

TABLE_V_Q = np.array([[0.5, 0.5], [0.0, 0.0], [0.0, -0.8]])


class ScaledTask1(eqx.Module):
    """A learned stand-in for Task 1 (eq. 25) that is ``alpha`` times the true model, the
    relation Table V reports (alpha = 0.302); ``matrices`` takes one q, as learn's models do."""

    alpha: float = 0.302

    def matrices(self, q):
        K = jnp.array([[2.1, -2.1], [-2.1, 6.7]])
        m = jnp.array([1.0, 1.8])
        return {
            "M": self.alpha * jnp.diag(m),
            "M_inv": jnp.diag(1.0 / (self.alpha * m)),
            "D": self.alpha * jnp.array([[0.3, -0.3], [-0.3, 0.3]]),
            "G": self.alpha * K @ q,
            "A": jnp.zeros((2, 0)),
        }


@pytest.fixture(scope="module")
def task1():
    return TrueModel("task1")


def test_table_v_alpha_from_the_true_model(task1, tmp_path):
    q = np.concatenate([TABLE_V_Q, sample_q([-1, -1], [1, 1], 17, seed=1)])
    result = analyze(task1, ScaledTask1(), q, options={"smooth": {"degree": 1}})
    assert isinstance(result, AnalysisResult)
    assert list(result.results) == ["pointwise", "joint", "alpha", "constant", "smooth"]
    alpha = result.results["alpha"]
    assert abs(alpha.params["alpha"] - 0.302) < 1e-12
    for name, r in result.results.items():
        assert str(r.status) == "success", name
        assert max(r.residual.values()) < 1e-12, name
        assert abs(r.alpha - 0.302) < 1e-10 and r.distance_all < 1e-10, name
    # at q = [0, 0] the true G is zero, and so is the learned one: residual 0, not NaN
    assert result.results["pointwise"].residuals["G"][1] == 0.0
    assert result.true.A.shape == (20, 2, 0) and "A" not in alpha.residual

    paths = write_report(result, tmp_path / "report", max_table_q=3)
    for name in ("report.md", "analysis.json", "summary.csv", "table_alpha.tex", "P_entries.png"):
        assert paths[name].is_file(), name
    data = json.loads(paths["analysis.json"].read_text())
    assert data["transforms"]["alpha"]["params"]["alpha"] == alpha.params["alpha"]
    np.testing.assert_allclose(data["q"], q)
    np.testing.assert_allclose(data["true"]["M"][0], [[1.0, 0.0], [0.0, 1.8]])
    columns, rows = read_csv(paths["table_pointwise.csv"])
    assert columns[:3] == ("q", "true M[1]", "true M[2]") and len(rows) == 2 * len(q)
    assert rows[1][columns.index("true G")] == pytest.approx(2.3)  # eq. 25 at q = [0.5, 0.5]
    report = paths["report.md"].read_text()
    assert "alpha = 0.302" in report and "| alpha | ok | recovered |" in report
    assert "First 3 of 20 q" in report and "![P entries](P_entries.png)" in report
    assert summary_numbers(result)["alpha"]["alpha"] == pytest.approx(0.302, abs=1e-12)


def test_hamiltonian_model_gets_the_direct_comparison(task1, tmp_path):
    config = ModelConfig(
        kind="hamiltonian", n=2, m=0, mass=(8, 1), potential=(8, 1), damping=(4, 1)
    )
    model = make_model(config, key=jax.random.PRNGKey(0))
    q = sample_q([-1, -1], [1, 1], 8, seed=2)
    result = analyze(task1, model, q, transforms=("pointwise",))
    assert list(result.results) == ["direct", "pointwise"]
    direct = result.results["direct"]
    assert list(direct.residual) == ["M_inv", "D", "G"]
    one = np.asarray(model.matrices(jnp.asarray(q[3]))["M_inv"])  # vmap equals one call
    np.testing.assert_allclose(result.learned.M_inv[3], one, rtol=1e-12)
    Minv = result.learned.M_inv
    ref = np.linalg.norm(Minv - task1.M_inv(q)) / np.linalg.norm(task1.M_inv(q))
    assert direct.residual["M_inv"] == pytest.approx(ref, rel=1e-12)
    # pointwise P = M M^-1 (learned M^-1 used directly): exact for M whatever the network
    assert result.results["pointwise"].residual["M"] < 1e-12
    paths = write_report(result, tmp_path, plots=False)
    assert "true M_inv[1]" in read_csv(paths["table_direct.csv"])[0]
    assert not any(p.suffix == ".png" for p in paths.values())


def test_already_evaluated_matrices_are_accepted(task1):
    q = TABLE_V_Q
    true = {k: getattr(task1, k)(q) for k in ("M", "D", "G")}
    learned = {k: 2.0 * v for k, v in true.items()}
    result = analyze(true, learned, q, transforms=("alpha", "direct"))
    assert result.results["alpha"].params["alpha"] == pytest.approx(2.0, abs=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"transforms": ("procrustes",)}, "transform: unknown 'procrustes'"),
        ({"options": {"smooth": {"degree": 2}}, "transforms": ("alpha",)}, "not among"),
        ({"options": {"alpha": {"degree": 2}}, "transforms": ("alpha",)}, "unknown option"),
        ({"q": np.zeros((3, 3))}, "q: expected length n = 2"),
    ],
)
def test_bad_input(task1, kwargs, match):
    q = kwargs.pop("q", TABLE_V_Q)
    with pytest.raises(UserError, match=match):
        analyze(task1, ScaledTask1(), q, **kwargs)


def test_black_box_and_bad_out_dir(task1, tmp_path):
    box = make_model(
        ModelConfig(kind="blackbox", n=2, m=0, hidden=(4, 1)), key=jax.random.PRNGKey(0)
    )
    with pytest.raises(Exception, match="no physical matrices") as info:
        analyze(task1, box, TABLE_V_Q)
    assert getattr(type(info.value), "softpinn_user_error", False)
    result = analyze(task1, ScaledTask1(), TABLE_V_Q, transforms=("alpha",))
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="is not a directory"):
        write_report(result, tmp_path / "file")
    with pytest.raises(UserError, match="high: expected >= low"):
        sample_q([0, 1], [1, 0], 3)


def test_analysis_q_puts_the_paper_q_first(task1):
    q, k = analysis_q(task1.spec, count=6, seed=3)
    assert k == 3 and q.shape == (9, 2)
    np.testing.assert_array_equal(q[:3], TABLE_V_Q)
    assert np.all(np.abs(q[3:]) <= 1.0)  # task1's [data] q0_low, q0_high
    np.testing.assert_array_equal(analysis_q(task1.spec, count=6, seed=3)[0], q)
    only, k = analysis_q(task1.spec, count=0)
    assert k == 3 and len(only) == 3
    with pytest.raises(UserError, match="no q"):
        analysis_q(task1.spec, count=0, paper=False)


def test_task4_scale_recovers_a_known_P():
    """Task 4's true matrices (M ~ 1e-3 beside G ~ 1) mapped by a known smooth P(q): every
    fit that can represent it gets it back; the smooth one also at held-out q."""
    task4 = TrueModel("task4")
    q, k = analysis_q(task4.spec, count=60, seed=0)
    true = {key: getattr(task4, key)(q) for key in ("M", "D", "G", "A")}
    P = 1.5 * np.eye(3) + 0.2 * q[:, :, None] * np.array([1.0, -0.5, 0.3])[None, None, :]
    Pinv = np.linalg.inv(P)
    learned = {key: Pinv @ v for key, v in true.items() if key != "G"}
    learned["G"] = (Pinv @ true["G"][:, :, None])[:, :, 0]
    result = analyze(task4, learned, q, options={"smooth": {"degree": 1, "seed": 1}})
    for name in ("pointwise", "joint", "smooth"):
        np.testing.assert_allclose(result.results[name].P, P, atol=1e-9, err_msg=name)
    smooth = result.results["smooth"]
    assert max(smooth.params["residual_heldout"].values()) < 1e-10
    assert result.results["constant"].residual_total > 1e-2  # P varies with q


def test_sweeps_put_the_learned_matrices_beside_the_true_ones_along_each_coordinate(
        task1, tmp_path):
    from softpinn.bridge.analysis.sweeps import POINTS, sweep_points

    q = np.concatenate([TABLE_V_Q, sample_q([-1, -0.5], [1, 0.5], 17, seed=2)])
    result = analyze(task1, ScaledTask1(), q, transforms=("alpha",))
    sw = result.sweeps
    # alpha is the headline transform of a Lagrangian-like model: c = 1/alpha undoes it
    assert sw.transform == "alpha" and sw.scale == pytest.approx(1 / 0.302)
    assert [s.coordinate for s in sw.sweeps] == [0, 1]  # q1 spreads over [-1, 1], q2 less
    for s in sw.sweeps:
        assert s.q.shape == (POINTS, 2) and s.name == f"q{s.coordinate + 1} [m]"  # with units
        other = 1 - s.coordinate
        np.testing.assert_allclose(s.q[:, other], np.median(q[:, other]))
        assert s.values[0] == q[:, s.coordinate].min() and s.values[-1] == q[:, s.coordinate].max()
        for k in ("M", "D", "G"):  # the scaled learned model is the true one exactly
            np.testing.assert_allclose(getattr(s.learned, k), getattr(s.true, k), atol=1e-12)
    paths = write_report(result, tmp_path / "r")
    assert paths["sweeps.png"].is_file() and "![sweeps](sweeps.png)" in paths[
        "report.md"].read_text()
    assert json.loads(paths["analysis.json"].read_text())["sweeps"]["transform"] == "alpha"
    # a coordinate that never moves is not swept; one configuration gives no sweep at all
    assert [j for j, _ in sweep_points(np.array([[0.0, 1.0], [2.0, 1.0]]))] == [0]
    assert sweep_points(np.array([[0.0, 1.0]])) == []
