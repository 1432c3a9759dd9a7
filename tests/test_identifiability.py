"""bridge.analysis.identifiability: the first-order sensitivities of eq. 10's targets to the mass
matrix, and what a change of D and G(q) can explain in their place."""

import numpy as np
import pytest

from softpinn.bridge.analysis.identifiability import mass_identifiability, mass_sensitivities


def _spd(rng, N, n):
    B = rng.normal(size=(N, n, n))
    return B @ B.transpose(0, 2, 1) + n * np.eye(n)


def test_sensitivities_are_the_derivative_of_the_acceleration_at_fixed_force():
    rng = np.random.default_rng(0)
    N, n = 7, 3
    M, a = _spd(rng, N, n), rng.normal(size=(N, n))
    J, pairs = mass_sensitivities(M, a)
    f = np.einsum("bij,bj->bi", M, a)  # the force, held fixed
    eps = 1e-6
    for k, (i, j) in enumerate(pairs):
        E = np.zeros_like(M)
        s = np.sqrt(M[:, i, i] * M[:, j, j])
        E[:, i, j] = E[:, j, i] = s
        up = np.linalg.solve(M + eps * E, f[..., None])[..., 0]
        down = np.linalg.solve(M - eps * E, f[..., None])[..., 0]
        np.testing.assert_allclose(J[:, k] * np.sqrt(N), ((up - down) / (2 * eps)).ravel(),
                                   rtol=1e-6, atol=1e-9)


def test_accelerations_proportional_to_velocities_cannot_tell_mass_from_damping():
    """q̈ = -c q̇ at every sample, M constant: a change of M is a change of the constant D
    (δD = c δM); nothing is left."""
    rng = np.random.default_rng(1)
    N, n = 400, 2
    M = np.broadcast_to(_spd(rng, 1, n), (N, n, n)).copy()
    q, qd = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    res = mass_identifiability(M, q, qd, -2.0 * qd, g_degree=0)
    assert max(res["fraction_left"].values()) < 1e-8
    assert max(res["singular_values"]["velocity_after_D_G"]) < 1e-8
    assert min(res["singular_values"]["velocity"]) > 0.1  # M alone would be seen


@pytest.mark.parametrize("degree, hidden", [(0, False), (1, True)])
def test_a_linear_spring_hides_a_constant_mass_from_a_linear_potential(degree, hidden):
    """q̈ = -K q with a constant M: δM q̈ = -δM K q is linear in q, which a G(q) of degree 1
    absorbs and a constant G does not."""
    rng = np.random.default_rng(2)
    N, n = 500, 2
    M = np.broadcast_to(np.array([[2.0, 0.3], [0.3, 1.0]]), (N, n, n)).copy()
    K = np.array([[3.0, -1.0], [-1.0, 2.0]])
    q, qd = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    res = mass_identifiability(M, q, qd, -q @ K.T, g_degree=degree)
    left = max(res["fraction_left"].values())
    assert (left < 1e-8) if hidden else (left > 0.5)


def test_momentum_data_see_the_mass_matrix_alone():
    rng = np.random.default_rng(3)
    N, n = 300, 3
    M = _spd(rng, N, n)
    q, qd, qdd = (rng.normal(size=(N, n)) for _ in range(3))
    res = mass_identifiability(M, q, qd, qdd, g_degree=1, names=["a", "b", "c"])
    momentum = res["singular_values"]["momentum"]
    assert len(momentum) == 6 and min(momentum) > 0.05
    assert set(res["fraction_left"]) == {"a-a", "a-b", "a-c", "b-b", "b-c", "c-c"}
    assert 0.0 < min(res["fraction_left"].values()) <= 1.0
