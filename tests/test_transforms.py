"""bridge.transforms: the matrix-equivalence fits recover known transforms from synthetic data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softpinn.bridge.analysis.transforms import (
    TRANSFORMS,
    MatrixStack,
    Status,
    compare_direct,
    fit_alpha,
    fit_constant,
    fit_joint,
    fit_pointwise,
    fit_smooth,
    fit_transform,
    make_basis,
)
from softpinn.errors import UserError

N_DOF = 3


def true_matrices(q: np.ndarray) -> dict[str, np.ndarray]:
    """A smooth, Task-4-like set of true matrices: M ~ 1e-3, D = 0.1 I, G ~ 1, A ~ I."""
    a, b, c = q.T
    N = len(q)
    B = np.zeros((N, 3, 3))
    B[:, 0, 0] = 1 + 0.3 * np.sin(a)
    B[:, 0, 1] = 0.2 * b
    B[:, 0, 2] = 0.1
    B[:, 1, 1] = 1 + 0.2 * c * c
    B[:, 1, 2] = 0.3 * np.cos(a)
    B[:, 2, 0] = 0.1 * a * b
    B[:, 2, 2] = 2.0
    M = 1e-3 * B @ np.swapaxes(B, 1, 2)
    D = np.broadcast_to(0.1 * np.eye(3), (N, 3, 3)).copy()
    G = np.stack([np.sin(a), b * c, np.cos(c)], axis=1)
    A = np.eye(3) + 0.1 * q[:, :, None] * q[:, None, ::-1]
    return {"M": M, "D": D, "G": G, "A": A}


def P_polynomial(q: np.ndarray) -> np.ndarray:
    """A smooth invertible P(q), a polynomial of degree 2 in q."""
    a, b, c = q.T
    P = np.zeros((len(q), 3, 3)) + 2 * np.eye(3)
    P[:, 0, 0] += 0.5 * a
    P[:, 0, 1] += 0.5 * a * b
    P[:, 0, 2] += 0.15
    P[:, 1, 0] += 0.05
    P[:, 1, 1] += 0.5 * c
    P[:, 1, 2] += 0.5 * a * a
    P[:, 2, 0] += 0.5 * b
    P[:, 2, 1] += 0.1 * c
    P[:, 2, 2] += 0.25 * b * c
    return P


def P_transcendental(q: np.ndarray) -> np.ndarray:
    """A smooth invertible P(q) outside every polynomial basis."""
    a, b, c = q.T
    P = np.zeros((len(q), 3, 3)) + 2 * np.eye(3)
    P[:, 0, 0] += 0.5 * np.sin(a)
    P[:, 0, 1] += 0.15 * np.exp(b)
    P[:, 1, 1] += 0.5 * np.tanh(c)
    P[:, 1, 2] += 0.5 * a * a
    P[:, 2, 0] += 0.5 * b
    P[:, 2, 2] += 0.25 * np.cos(b * c)
    return P


def learned_from(true: dict, P: np.ndarray, *, hamiltonian: bool = False) -> dict:
    """Learned matrices with ``true = P learned``: every matrix times P^-1."""
    Pinv = np.linalg.inv(P)
    out = {k: Pinv @ v for k, v in true.items() if k != "G"}
    out["G"] = (Pinv @ true["G"][:, :, None])[:, :, 0]
    if hamiltonian:  # a Hamiltonian network gives M^-1 instead of M
        out["M_inv"] = np.linalg.inv(out.pop("M"))
    return out


@pytest.fixture(scope="module")
def q():
    return np.random.default_rng(0).uniform(-1, 1, (60, N_DOF))


@pytest.fixture(scope="module")
def true(q):
    return true_matrices(q)


@pytest.mark.parametrize("hamiltonian", [False, True])
@pytest.mark.parametrize("Pfun", [P_polynomial, P_transcendental])
@pytest.mark.parametrize("fit", [fit_pointwise, fit_joint])
def test_pointwise_fits_recover_P(q, true, fit, Pfun, hamiltonian):
    P = Pfun(q)
    res = fit(true, learned_from(true, P, hamiltonian=hamiltonian), q)
    assert res.status == Status.SUCCESS
    np.testing.assert_allclose(res.P, P, rtol=0, atol=1e-10)
    for k in ("M", "D", "A", "G"):
        assert np.max(res.residuals[k]) < 1e-10
        assert res.residual[k] < 1e-10


def test_pointwise_maps_only_M_exactly(q, true):
    """A learned D that is not P^-1 D shows up in D's residual, not in M's."""
    learned = learned_from(true, P_polynomial(q))
    learned["D"] = learned["D"] * 1.1
    res = fit_pointwise(true, learned, q)
    assert res.residual["M"] < 1e-12
    np.testing.assert_allclose(res.residual["D"], 0.1, rtol=1e-9)


def test_joint_weighting_balances_small_blocks(q, true):
    """With M ~ 1e-3 and G ~ 1, an error in G swamps M unless each block is normalised."""
    learned = learned_from(true, P_polynomial(q))
    learned["G"] = learned["G"] + 0.05 * np.random.default_rng(1).standard_normal((len(q), 3))
    none = fit_joint(true, learned, q, weighting="none", blocks=("M", "G"))
    frob = fit_joint(true, learned, q, weighting="frobenius", blocks=("M", "G"))
    # unweighted, G (~1) is fitted exactly at M's (~1e-3) expense; normalised, both count
    assert none.residual["G"] < 1e-4 < 0.05 < none.residual["M"]
    assert frob.residual["M"] < 0.8 * none.residual["M"] and frob.residual["G"] > 1e-2
    np.testing.assert_allclose(frob.params["weights"]["M"], 1 / np.linalg.norm(true["M"]))
    explicit = fit_joint(true, learned, q, weighting={"M": 1.0, "G": 1.0}, blocks=("M", "G"))
    np.testing.assert_allclose(explicit.P, none.P, atol=1e-12)


@pytest.mark.parametrize("hamiltonian", [False, True])
def test_alpha_recovers_scale_exactly(q, true, hamiltonian):
    alpha = 0.302  # Table V
    learned = {k: alpha * v for k, v in true.items()}
    if hamiltonian:
        learned["M_inv"] = np.linalg.inv(learned.pop("M"))
    res = fit_alpha(true, learned, q)
    assert res.status == Status.SUCCESS
    assert abs(res.params["alpha"] - alpha) < 1e-12
    assert abs(res.alpha - alpha) < 1e-12
    np.testing.assert_allclose(res.params["alpha_per_q"], alpha, rtol=1e-12)
    for k in ("M", "D", "A", "G"):
        assert abs(res.params["alpha_per_matrix"][k] - alpha) < 1e-12
        assert res.residual[k] < 1e-13
    np.testing.assert_allclose(res.P, np.broadcast_to(np.eye(3) / alpha, res.P.shape), rtol=1e-12)
    assert np.max(res.distance) < 1e-14 and res.distance_all < 1e-14
    np.testing.assert_allclose(res.model(q[:2]), np.broadcast_to(np.eye(3) / alpha, (2, 3, 3)))


def test_alpha_closed_form_matches_lstsq(q, true):
    learned = learned_from(true, P_polynomial(q))
    res = fit_alpha(true, learned, q, blocks=("M",), weighting="none")
    x, y = true["M"].ravel(), learned["M"].ravel()
    ref = np.linalg.lstsq(x[:, None], y, rcond=None)[0][0]
    assert abs(res.params["alpha"] - ref) < 1e-12 * abs(ref)


def test_constant_recovers_constant_P(q, true):
    P0 = np.array([[2.0, 0.3, -0.1], [0.2, 1.5, 0.4], [0.0, -0.3, 0.8]])
    P = np.broadcast_to(P0, (len(q), 3, 3))
    res = fit_constant(true, learned_from(true, P), q)
    assert res.status == Status.SUCCESS and res.params["rank"] == 3
    np.testing.assert_allclose(res.P, P, atol=1e-10)
    assert max(res.residual.values()) < 1e-10
    np.testing.assert_allclose(
        res.model(np.zeros((4, 3))), np.broadcast_to(P0, (4, 3, 3)), atol=1e-10
    )
    # a varying P cannot be matched by a constant one
    varying = fit_constant(true, learned_from(true, P_polynomial(q)), q)
    assert varying.residual_total > 1e-2


def test_smooth_in_span_generalises(q, true):
    P = P_polynomial(q)
    res = fit_smooth(true, learned_from(true, P), q, degree=2, heldout=0.25, seed=3)
    train = res.params["train"]
    assert res.status == Status.SUCCESS
    assert train.sum() == 45 and (~train).sum() == 15
    assert max(res.params["residual_heldout"].values()) < 1e-10
    np.testing.assert_allclose(res.P, P, atol=1e-10)
    q_new = np.random.default_rng(7).uniform(-1, 1, (5, 3))
    np.testing.assert_allclose(res.model(q_new), P_polynomial(q_new), atol=1e-9)


def test_smooth_out_of_span_is_reasonable(q, true):
    P = P_transcendental(q)
    learned = learned_from(true, P)
    held = {}
    for degree in (1, 2, 4):
        res = fit_smooth(true, learned, q, degree=degree, seed=3)
        held[degree] = max(res.params["residual_heldout"].values())
    rbf = fit_smooth(true, learned, q, basis="rbf", n_centers=20, seed=3)
    assert held[4] < held[2] < held[1]
    assert held[2] < 3e-2 and held[4] < 1e-2
    assert max(rbf.params["residual_heldout"].values()) < 5e-2


def test_smooth_ridge_and_underdetermined(q, true):
    learned = learned_from(true, P_transcendental(q))
    plain = fit_smooth(true, learned, q, degree=3)
    ridged = fit_smooth(true, learned, q, degree=3, ridge=1e-2)
    assert np.linalg.norm(ridged.params["coefficients"]) < np.linalg.norm(
        plain.params["coefficients"]
    )
    few = fit_smooth(true, learned, q, degree=4, train=np.arange(len(q)) < 4)
    assert few.status == Status.UNDERDETERMINED
    assert "equations" in few.message


def test_polynomial_basis_size():
    basis = make_basis(np.random.default_rng(0).uniform(-1, 1, (10, 3)), degree=3)
    assert basis.size == 20  # C(3 + 3, 3) monomials of degree <= 3 in 3 variables


def test_direct_comparison_for_hamiltonian(q, true):
    learned = dict(true)
    learned["M_inv"] = np.linalg.inv(true["M"]) * 1.02
    del learned["M"]
    learned["D"] = true["D"] * 0.9
    res = compare_direct(true, learned, q)
    np.testing.assert_array_equal(res.P, np.broadcast_to(np.eye(3), (len(q), 3, 3)))
    assert list(res.residual) == ["M_inv", "D", "A", "G"]
    np.testing.assert_allclose(res.residual["M_inv"], 0.02, rtol=1e-9)
    np.testing.assert_allclose(res.residuals["M_inv"], 0.02, rtol=1e-9)
    np.testing.assert_allclose(res.params["residual_M"], 1 - 1 / 1.02, rtol=1e-9)
    np.testing.assert_allclose(res.residual["D"], 0.1, rtol=1e-9)
    assert res.residual["G"] == 0 and res.residual["A"] == 0
    assert res.scale_all == 1 and res.distance_all == 0


def test_identity_distance_by_hand(q, true):
    P0 = np.diag([1.0, 2.0, 3.0])
    res = fit_constant(true, learned_from(true, np.broadcast_to(P0, (len(q), 3, 3))), q)
    np.testing.assert_allclose(res.scale, 2.0)
    np.testing.assert_allclose(res.distance, np.sqrt(2) / np.sqrt(14), rtol=1e-9)


def test_zero_true_matrix_residual(q, true):
    """At q = 0 Task 1's G is zero: a relative residual is 0 if learned is zero, else NaN."""
    t = {k: v[:3].copy() for k, v in true.items()}
    t["G"][0] = 0.0
    learned = {k: v.copy() for k, v in t.items()}
    assert compare_direct(t, learned).residuals["G"][0] == 0.0
    learned["G"][0] = 1e-3
    res = compare_direct(t, learned)
    assert np.isnan(res.residuals["G"][0]) and np.isfinite(res.residual["G"])


def test_singular_learned_mass(q, true):
    learned = learned_from(true, P_polynomial(q))
    learned["M"][5] = 0.0
    res = fit_pointwise(true, learned, q)
    assert res.status == Status.SINGULAR and "1 of 60" in res.message
    assert np.all(np.isnan(res.P[5])) and np.isnan(res.residuals["M"][5])
    assert np.all(np.isfinite(np.delete(res.P, 5, axis=0)))
    assert res.residual["M"] < 1e-12 and np.isnan(res.scale[5])  # the other q are exact
    rank = fit_joint(true, {"M": learned["M"]}, q)
    assert rank.status == Status.RANK_DEFICIENT and rank.params["rank"][5] == 0


@pytest.mark.parametrize("name", TRANSFORMS)
def test_every_transform_by_name_is_json_ready(q, true, name):
    res = fit_transform(name, true, learned_from(true, P_polynomial(q)), q)
    text = json.dumps(res.to_dict(), allow_nan=False)
    assert json.loads(text)["name"] == name


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda t, l, q: fit_transform("procrustes", t, l, q), "unknown 'procrustes'"),
        (lambda t, l, q: fit_transform("joint", t, l, q, degree=2), "unknown option 'degree'"),
        (lambda t, l, q: fit_joint(t, l, q[:, :2]), "expected length n = 3.*got 2"),
        (lambda t, l, q: fit_joint(t, l, q[:5]), "q: expected N = 60.*got 5"),
        (
            lambda t, l, q: fit_joint(t, {**l, "M": l["M"][:, :2, :2]}, q),
            r"learned.D: expected n = 2 rows \(as M\), got 3",
        ),
        (
            lambda t, l, q: fit_joint(
                t, {k: v[:, :2, :2] if v.ndim == 3 else v[:, :2] for k, v in l.items()}, q[:, :2]
            ),
            "learned matrices: n = 2 .* true n = 3",
        ),
        (lambda t, l, q: fit_joint(t, {k: v[:7] for k, v in l.items()}), "N = 7 .* N = 60"),
        (lambda t, l, q: fit_joint(t, {**l, "A": l["A"][:, :, :2]}), "m = 2 inputs .* m = 3"),
        (lambda t, l, q: fit_joint(t, {**l, "G": l["G"][:, :, None]}), "G: expected shape"),
        (lambda t, l, q: fit_joint(t, {**l, "D": l["D"] * np.nan}), "D: contains NaN"),
        (lambda t, l, q: fit_joint(t, l, weighting="max"), "weighting: expected one of"),
        (lambda t, l, q: fit_joint(t, l, weighting={"M": 1.0}), "no weight for D"),
        (lambda t, l, q: fit_joint(t, {"M": l["M"]}, blocks=("D",)), "D requested"),
        (lambda t, l, q: fit_joint(t, l, blocks=("C",)), "unknown matrix 'C'"),
        (lambda t, l, q: fit_smooth(t, l, q, basis="fourier"), "basis: expected one of"),
        (lambda t, l, q: fit_smooth(t, l, None), "q is required"),
        (lambda t, l, q: fit_smooth(t, l, q, heldout=1.5), r"heldout: expected a fraction"),
        (lambda t, l, q: fit_smooth(t, l, q, ridge=-1.0), "ridge: expected"),
        (lambda t, l, q: fit_joint(t, {}), "no matrices given"),
        (lambda t, l, q: fit_joint(t, {"energy": 1.0}), "no matrices given"),
    ],
)
def test_bad_input_gives_one_line_user_error(q, true, call, match):
    learned = learned_from(true, P_polynomial(q))
    with pytest.raises(UserError, match=match) as info:
        call(true, learned, q)
    assert "\n" not in str(info.value)


def test_matrix_stack_fills_mass_from_inverse(true):
    Minv = np.linalg.inv(true["M"][:4])
    stack = MatrixStack(M_inv=Minv, name="learned")
    np.testing.assert_allclose(stack.mass(), true["M"][:4], rtol=1e-10)
    assert stack.N == 4 and stack.n == 3 and stack.m is None


@pytest.mark.parametrize("fit", [fit_joint, fit_constant, fit_alpha])
def test_zero_true_block_is_left_out_of_joint_fits(q, true, fit):
    """An undamped system (Task 2: D = 0) with a slightly damped learned model: the learned D̂
    must not pull P away from the transform that maps M and G (it did, weighted by 1/||D̂||)."""
    alpha = 0.5
    t = {k: v.copy() for k, v in true.items()}
    t["D"] = np.zeros_like(t["D"])
    learned = {k: alpha * v for k, v in t.items()}
    learned["D"] = 1e-3 * np.broadcast_to(np.eye(N_DOF), t["D"].shape).copy()
    res = fit(t, learned, q)
    assert "D" not in res.residual
    assert res.residual["M"] < 1e-12 and res.residual["G"] < 1e-12
    assert abs(res.alpha - alpha) < 1e-12
