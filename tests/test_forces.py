"""bridge.forces: learned against true force terms G, D q̇, A u along data samples."""

from __future__ import annotations

import json
from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from known_fields import Field, MassField
from test_analysis import ScaledTask1

from softpinn.bridge.analysis import analyze, sample_q
from softpinn.bridge.analysis.forces import (
    compare_forces,
    data_samples,
    force_terms,
    markdown_lines,
)
from softpinn.bridge.analysis.matrices import MatrixStack
from softpinn.bridge.analysis.transforms import fit_transform
from softpinn.bridge.figures.analysis import write_report
from softpinn.bridge.figures.matrices import plot_forces
from softpinn.errors import UserError
from softpinn.learn._models import HamiltonianNet, ModelConfig
from softpinn.symbolic.model._true_model import TrueModel


def _stacks(N=400, n=3, m=2, seed=0, mass=False):
    """Random matrices at N configurations, and velocities and inputs to go with them."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(N, n, n))
    D = B @ B.transpose(0, 2, 1) + np.eye(n)
    A = rng.normal(size=(N, n, m))
    G = rng.normal(size=(N, n))
    qd, u = rng.normal(size=(N, n)), rng.normal(size=(N, m))
    mats = {"D": D, "A": A, "G": G}
    if mass:
        L = rng.normal(size=(N, n, n))
        mats["M"] = L @ L.transpose(0, 2, 1) + 0.5 * np.eye(n)
    return mats, qd, u


class PTask1(eqx.Module):
    """Task 1's true matrices (eq. 25) seen through a known invertible P(q) = 1.5 I + 0.4 q b^T:
    M̂ = P⁻¹M, D̂ = P⁻¹D, Ĝ = P⁻¹G, one of the solutions a Lagrangian network may learn
    (Section IV). No scalar alpha relates them to the true ones."""

    def matrices(self, q):
        P = 1.5 * jnp.eye(2) + 0.4 * jnp.outer(q, jnp.array([1.0, -0.5]))
        Pinv = jnp.linalg.inv(P)
        K = jnp.array([[2.1, -2.1], [-2.1, 6.7]])
        M = Pinv @ jnp.diag(jnp.array([1.0, 1.8]))
        return {"M": M, "M_inv": jnp.linalg.inv(M),
                "D": Pinv @ jnp.array([[0.3, -0.3], [-0.3, 0.3]]), "G": Pinv @ K @ q,
                "A": jnp.zeros((2, 0))}  # fmt: skip


def test_terms_are_the_right_hand_side_of_eq_1():
    mats, qd, u = _stacks(N=5)
    terms = force_terms(MatrixStack(**mats), qd, u)
    k = 3
    np.testing.assert_allclose(terms["D_qd"][k], mats["D"][k] @ qd[k], rtol=1e-14)
    np.testing.assert_allclose(terms["A_u"][k], mats["A"][k] @ u[k], rtol=1e-14)
    np.testing.assert_allclose(
        terms["net"][k], mats["A"][k] @ u[k] - mats["G"][k] - mats["D"][k] @ qd[k], rtol=1e-13
    )


def test_exact_model_has_zero_errors_and_a_scaled_one_is_undone_by_scale():
    mats, qd, u = _stacks()
    true = MatrixStack(**mats)
    same = compare_forces(true, MatrixStack(**mats), qd, u)
    assert all(e == 0.0 for e in same.error.values())
    assert same.cancellation is None and "exactly" in same.message
    doubled = MatrixStack(**{k: 2.0 * v for k, v in mats.items()})
    r = compare_forces(true, doubled, qd, u, scale=0.5)
    assert max(r.error.values()) < 1e-15
    assert compare_forces(true, doubled, qd, u).error["G"] == pytest.approx(1.0, rel=1e-14)


def test_a_shared_error_of_G_and_A_at_equilibrium_cancels_in_the_net_force(tmp_path):
    """Inputs that balance the potential force (A u = G at every sample): a learned model with
    G and A both 5 % too large has the same net force, so the cancellation is 0."""
    mats, qd, u = _stacks(m=3)
    mats["G"] = np.einsum("kij,kj->ki", mats["A"], u)
    eps = 0.05
    learned = dict(mats, G=(1 + eps) * mats["G"], A=(1 + eps) * mats["A"])
    r = compare_forces(MatrixStack(**mats), MatrixStack(**learned), qd, u)
    assert r.error["G"] == pytest.approx(eps, rel=1e-12)
    assert r.error["A_u"] == pytest.approx(eps, rel=1e-12)
    assert r.error["D_qd"] == 0.0 and r.error["net"] < 1e-14
    assert r.cancellation < 1e-13 and r.alignment == pytest.approx(1.0, abs=1e-14)
    assert "cancel along the data" in r.message and "equilibrium" in r.message
    fig = plot_forces(r, path=tmp_path / "f.png")  # the four terms, then the errors of G, A u
    assert len(fig.axes) == 5 and (tmp_path / "f.png").is_file()
    with pytest.raises(UserError, match="no per-sample terms"):
        plot_forces(SimpleNamespace(terms={}))


def test_independent_errors_do_not_cancel():
    mats, qd, u = _stacks(N=4000)
    rng = np.random.default_rng(1)
    learned = {k: v + 0.01 * rng.normal(size=v.shape) for k, v in mats.items()}
    r = compare_forces(MatrixStack(**mats), MatrixStack(**learned), qd, u)
    assert 0.9 < r.cancellation < 1.1
    assert "do not cancel" in r.message
    assert abs(r.alignment) < 0.1  # unrelated random G and A u


def test_analyze_compares_forces_of_a_lagrangian_model_through_alpha(tmp_path):
    """ScaledTask1 is 0.302 times the true Task 1 model: divided by the fitted alpha its forces
    are the true ones; Task 1 has no inputs, so A u is zero and its error undefined."""
    task1 = TrueModel("task1")
    q = sample_q([-1, -1], [1, 1], 12, seed=3)
    rng = np.random.default_rng(4)
    qs, qd = rng.uniform(-1, 1, (30, 2)), rng.normal(size=(30, 2))
    meta = {"data": "/somewhere/data.npz", "trajectories": [0, 1, 2, 5]}
    result = analyze(task1, ScaledTask1(), q, transforms=("alpha",),
                     samples=(qs, qd, np.zeros((30, 0)), meta))
    f = result.forces
    assert f.samples == 30 and f.scale == pytest.approx(1 / 0.302, rel=1e-12)
    assert f.error["G"] < 1e-12 and f.error["D_qd"] < 1e-12 and f.error["net"] < 1e-12
    assert f.error["A_u"] is None and f.alignment is None
    assert f.meta["scale_from"] == "alpha"
    paths = write_report(result, tmp_path)
    assert paths["forces.png"].stat().st_size > 0
    saved = json.loads(paths["analysis.json"].read_text())["forces"]
    assert saved["error"]["A_u"] is None and saved["samples"] == 30
    text = paths["report.md"].read_text()
    assert "## Forces along the data" in text and "`data.npz` (trajectories 0-2, 5)" in text
    assert "| A u | 0 | — |" in text and "](forces.png)" in text
    fig = plot_forces(f)  # G, D q̇ and the net force; no inputs, so no panel of errors
    assert len(fig.axes) == 3
    # the samples' excitation of the true M's directions (bridge.analysis.excitation), saved
    # and reported with the coordinates' names
    from softpinn.bridge.analysis.excitation import inertial_share

    want = inertial_share(task1, qs, qd, np.zeros((30, 0)))
    saved = json.loads(paths["analysis.json"].read_text())
    for key, value in want.items():
        np.testing.assert_allclose(saved["excitation"][key], value, rtol=1e-12)
    assert "## What the data show of the inertia" in text
    assert f"| 1 | {saved['meta']['coordinates'][0]} | 1 | " in text  # mass 1.0, the lighter
    # without samples there is no force comparison, and no excitation
    bare = analyze(task1, ScaledTask1(), q, transforms=("alpha",))
    assert bare.forces is None and bare.excitation is None


def test_acceleration_terms_are_m_inverse_times_the_forces():
    mats, qd, u = _stacks(N=6, mass=True)
    stack = MatrixStack(**mats)
    forces, accel = force_terms(stack, qd, u), force_terms(stack, qd, u, "acceleration")
    for key in ("G", "D_qd", "A_u", "net"):
        np.testing.assert_allclose(mats["M"][2] @ accel[key][2], forces[key][2], rtol=1e-12)
    # M_inv alone does as well
    only_inv = MatrixStack(M_inv=np.linalg.inv(mats["M"]), G=mats["G"])
    np.testing.assert_allclose(force_terms(only_inv, qd, None, "acceleration")["G"],
                               accel["G"], rtol=1e-12)
    with pytest.raises(UserError, match="acceleration frame needs matrices.M or M_inv"):
        force_terms(MatrixStack(G=mats["G"]), qd, u, "acceleration")
    with pytest.raises(UserError, match=r"frame: expected one of \['force', 'acceleration'\]"):
        force_terms(stack, qd, u, "torque")


def test_accelerations_are_the_same_through_any_p_of_q():
    """A learned model P(q)⁻¹ [M D A G] has other forces but the same accelerations: the
    acceleration frame finds it exact where the force frame (and any scalar) cannot."""
    mats, qd, u = _stacks(mass=True)
    rng = np.random.default_rng(5)
    P = 2.0 * np.eye(3) + 0.3 * rng.normal(size=(400, 3, 3))
    Pinv = np.linalg.inv(P)
    learned = {k: Pinv @ v for k, v in mats.items() if k != "G"}
    learned["G"] = np.einsum("kij,kj->ki", Pinv, mats["G"])
    true, hat = MatrixStack(**mats), MatrixStack(**learned)
    r = compare_forces(true, hat, qd, u, frame="acceleration")
    assert r.frame == "acceleration" and max(r.error.values()) < 1e-12
    assert r.cancellation is None and "every acceleration term" in r.message
    assert compare_forces(true, hat, qd, u).error["G"] > 0.3
    # a 5 % error of A alone shows in M⁻¹A u and in the net acceleration, not elsewhere
    learned["A"] = 1.05 * learned["A"]
    r = compare_forces(true, MatrixStack(**learned), qd, u, frame="acceleration")
    assert r.error["A_u"] == pytest.approx(0.05, rel=1e-10)
    assert r.error["G"] < 1e-12 and r.error["D_qd"] < 1e-12 and r.error["net"] > 0.01
    assert r.to_dict()["frame"] == "acceleration"
    lines = "\n".join(markdown_lines(r.to_dict()))
    assert lines.startswith("## Accelerations along the data")
    assert "| M⁻¹A u |" in lines and "| M⁻¹(A u − G − D q̇) |" in lines


def test_analyze_compares_accelerations_of_a_model_related_by_p_of_q(tmp_path):
    """PTask1 is the true Task 1 model through a q-dependent P: no alpha explains it, so its
    forces scaled by 1/alpha are off, but its accelerations are the true ones."""
    task1 = TrueModel("task1")
    q = sample_q([-1, -1], [1, 1], 12, seed=3)
    rng = np.random.default_rng(6)
    qs, qd = rng.uniform(-1, 1, (40, 2)), rng.normal(size=(40, 2))
    result = analyze(task1, PTask1(), q, transforms=("alpha", "pointwise"),
                     samples=(qs, qd, np.zeros((40, 0))))
    assert result.results["alpha"].residual_total > 0.05  # no scalar fits
    assert result.forces.error["G"] > 0.05
    acc = result.accelerations
    assert acc.scale == 1 and acc.error["G"] < 1e-12 and acc.error["D_qd"] < 1e-12
    assert acc.error["net"] < 1e-12 and acc.error["A_u"] is None
    paths = write_report(result, tmp_path)
    assert paths["accelerations.png"].stat().st_size > 0
    text = paths["report.md"].read_text()
    assert "## Forces along the data" in text and "## Accelerations along the data" in text
    assert "](accelerations.png)" in text
    saved = json.loads(paths["analysis.json"].read_text())["accelerations"]
    assert saved["frame"] == "acceleration" and saved["error"]["A_u"] is None
    # without alpha, the forces are not compared but the accelerations are
    bare = analyze(task1, PTask1(), q, transforms=("pointwise",),
                   samples=(qs, qd, np.zeros((40, 0))))
    assert bare.forces is None and bare.accelerations.error["net"] < 1e-12
    assert fit_transform("pointwise", result.true, result.learned).residual_total < 1e-12


def test_analyze_compares_the_whole_acceleration_of_a_network():
    """A Hamiltonian network built from Task 1's true fields (eq. 25): every force, every
    acceleration term and the whole q̈ (its qdd through the momentum) match the truth; the same
    network with a 10 % stiffer potential has 10 % off G, and q̈ off by what that makes."""
    task1 = TrueModel("task1")
    K = jnp.array([[2.1, -2.1], [-2.1, 6.7]])

    def net(stiff=1.0):
        return HamiltonianNet(
            config=ModelConfig(kind="hamiltonian", n=2, m=0),
            mass=MassField(lambda q: jnp.diag(1.0 / jnp.array([1.0, 1.8])) + 0.0 * q[0]),
            potential=Field(lambda q: 0.5 * stiff * q @ K @ q),
            damping=Field(lambda q: jnp.array([[0.3, -0.3], [-0.3, 0.3]]) + 0.0 * q[0]),
            input_map=Field(lambda q: jnp.zeros((2, 0))),
        )

    rng = np.random.default_rng(8)
    qs, qd = rng.uniform(-1, 1, (25, 2)), rng.normal(size=(25, 2))
    q = sample_q([-1, -1], [1, 1], 4, seed=0)
    samples = (qs, qd, np.zeros((25, 0)))
    acc = analyze(task1, net(), q, transforms=("alpha",), samples=samples).accelerations
    assert acc.error["qdd"] < 1e-12 and acc.error["net"] < 1e-12
    none = analyze(task1, net(), q, transforms=("alpha",), samples=(qs, qd, None))
    assert none.accelerations.error["qdd"] < 1e-12  # u = None: no inputs
    np.testing.assert_allclose(acc.terms["qdd"][0], task1.qdd(qs, qd), rtol=1e-12)
    stiff = analyze(task1, net(1.1), q, transforms=("alpha",), samples=samples)
    a = stiff.accelerations
    assert a.error["G"] == pytest.approx(0.1, rel=1e-10) and a.error["D_qd"] < 1e-12
    e = 0.1 * a.terms["G"][0]  # q̈ = M⁻¹(−G − D q̇): off by −0.1 M⁻¹G
    assert a.error["qdd"] == pytest.approx(
        np.linalg.norm(e) / np.linalg.norm(a.terms["qdd"][0]), rel=1e-10)
    assert "qdd" not in stiff.forces.error  # the force frame has no q̈
    # per coordinate: the error of each component of q̈ against that component
    col = [np.linalg.norm(e[:, i]) / np.linalg.norm(a.terms["qdd"][0][:, i]) for i in range(2)]
    assert a.qdd_per_coordinate == pytest.approx(col, rel=1e-10)
    assert acc.qdd_per_coordinate[0] < 1e-12 and stiff.forces.qdd_per_coordinate is None
    assert a.to_dict()["qdd_per_coordinate"] == a.qdd_per_coordinate
    lines = "\n".join(markdown_lines(a.to_dict()))
    assert "| q̈ (C q̇ too) |" in lines and "q̈'s relative error per coordinate of q: " in lines
    with pytest.raises(UserError, match="qdd: the whole acceleration is compared in the"):
        mats, qd3, u3 = _stacks(N=5, mass=True)
        compare_forces(MatrixStack(**mats), MatrixStack(**mats), qd3, u3, qdd=(qd3, qd3))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"qd": np.zeros((5, 3))}, r"qd: expected shape \(400, 3\)"),
        ({"u": np.zeros((400, 1))}, r"u: expected shape \(400, 2\)"),
        ({"qd": np.full((400, 3), np.nan)}, "qd: contains NaN"),
        ({"scale": 0.0}, "scale: expected a finite non-zero"),
        ({"learned_n": 2}, "does not match the true n = 3"),
    ],
)
def test_bad_input(change, match):
    mats, qd, u = _stacks()
    learned = MatrixStack(**mats)
    if change.pop("learned_n", None):
        learned = MatrixStack(G=mats["G"][:, :2])
    kwargs = {"qd": qd, "u": u, "scale": 1.0, **change}
    with pytest.raises(UserError, match=match):
        compare_forces(MatrixStack(**mats), learned, **kwargs)


def test_analyze_rejects_bad_samples():
    task1 = TrueModel("task1")
    q = sample_q([-1, -1], [1, 1], 4, seed=0)
    with pytest.raises(UserError, match=r"samples: expected \(q, qd, u\)"):
        analyze(task1, ScaledTask1(), q, transforms=("alpha",), samples=(q,))
    with pytest.raises(UserError, match="q: expected length n = 2"):
        analyze(task1, ScaledTask1(), q, transforms=("alpha",),
                samples=(np.zeros((4, 3)), q, np.zeros((4, 0))))


def test_data_samples_are_seeded_and_stay_in_the_trajectories():
    traj = np.repeat(np.arange(5), 100)
    data = SimpleNamespace(
        path="d.npz", sha256="abc", traj=traj, q=np.arange(500.0)[:, None],
        qd=-np.arange(500.0)[:, None], u=np.zeros((500, 0)),
    )  # fmt: skip
    q, qd, u, meta = data_samples(data, [1, 3], count=50, seed=7)
    assert len(q) == 50 and np.all(np.isin(traj[q[:, 0].astype(int)], [1, 3]))
    np.testing.assert_array_equal(qd, -q)
    np.testing.assert_array_equal(data_samples(data, [1, 3], count=50, seed=7)[0], q)
    assert meta["pool"] == 200 and meta["trajectories"] == [1, 3]
    assert len(data_samples(data, None, count=10_000)[0]) == 500  # all of them, no more
    with pytest.raises(UserError, match=r"trajectories: \[9\] are not in the data set d.npz"):
        data_samples(data, [1, 9])
    with pytest.raises(UserError, match="samples: expected a positive count"):
        data_samples(data, None, count=0)


def test_markdown_lines_without_heading():
    assert markdown_lines(None) == []
    mats, qd, u = _stacks()
    d = compare_forces(MatrixStack(**mats), MatrixStack(**mats), qd, u).to_dict()
    lines = markdown_lines(d, heading=None)
    assert lines[0].startswith("Force terms along 400 data samples")
    assert "| A u − G − D q̇ |" in "\n".join(lines)
