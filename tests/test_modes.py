"""Linearised dynamics: the true Jacobian against the preset's hand-written matrices, a known
learned model giving back the true eigenvalues (and α-scaled ones the same), an unstable learned
potential seen as a positive real part, the formatting and the bad-input messages."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from known_fields import Field, MassField

from softpinn.bridge.analysis.modes import format_modes, modes, true_jacobian
from softpinn.errors import UserError
from softpinn.learn._models import LagrangianNet, ModelConfig
from softpinn.learn._nets import ZeroMatrix
from softpinn.symbolic.model._true_model import TrueModel

jax.config.update("jax_enable_x64", True)

# task1.toml: masses 1.0 and 1.8; k1 = 2.1 between the masses, k2 = 4.6 to the ground;
# b = 0.3 between the masses
M = np.diag([1.0, 1.8])
K = np.array([[2.1, -2.1], [-2.1, 2.1 + 4.6]])
B = 0.3 * np.array([[1.0, -1.0], [-1.0, 1.0]])
STATE_MATRIX = np.block([[np.zeros((2, 2)), np.eye(2)],
                         [-np.linalg.solve(M, K), -np.linalg.solve(M, B)]])


def _known_model(alpha=1.0, stiffness=K):
    """A Lagrangian model whose sub-networks are α times task1's true matrices."""
    return LagrangianNet(
        config=ModelConfig(kind="lagrangian", n=2, m=0),
        mass=MassField(lambda q: alpha * jnp.asarray(M) + 0.0 * q[0]),
        potential=Field(lambda q: 0.5 * alpha * q @ jnp.asarray(stiffness) @ q),
        damping=Field(lambda q: alpha * jnp.asarray(B) + 0.0 * q[0]),
        input_map=ZeroMatrix((2, 0)),
    )


def _complex(pairs):
    return np.array([complex(a, b) for a, b in pairs])


@pytest.fixture(scope="module")
def task1():
    return TrueModel("task1")


def test_true_jacobian_is_the_hand_written_state_matrix(task1):
    x = np.array([0.3, -0.2, 0.0, 0.0])
    np.testing.assert_allclose(true_jacobian(task1, x, np.zeros(0)), STATE_MATRIX, atol=1e-7)


@pytest.mark.parametrize("alpha", [1.0, 0.3])
def test_a_model_equal_to_the_truth_up_to_alpha_has_the_true_modes(task1, alpha):
    out = modes(task1, _known_model(alpha), [0.1, -0.4], None)
    expected = np.linalg.eigvals(STATE_MATRIX)
    for side in ("true", "learned"):
        got = _complex(out[side])
        np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(expected), atol=1e-6)
        assert out[f"{side}_max_real"] < 0
    # sorted fastest decay first
    re = [p[0] for p in out["learned"]]
    assert re == sorted(re)
    assert out["state"] == "velocity" and out["q"] == [0.1, -0.4] and out["u"] == []


def test_an_unstable_learned_potential_shows_a_positive_real_part(task1):
    out = modes(task1, _known_model(stiffness=-K), [0.0, 0.0], None)
    assert out["learned_max_real"] > 0.5 and out["true_max_real"] < 0


def test_format_modes_writes_conjugate_pairs_once():
    text = format_modes([[-288.0, 0.0], [-1.32, -4.97], [-1.32, 4.97], [0.24, 0.0]])
    assert text == "-288, -1.32 ± 4.97i, 0.24"


def test_bad_q_and_u_are_one_line_errors(task1):
    with pytest.raises(UserError, match=r"modes: q needs 2 values, got 3"):
        modes(task1, _known_model(), [0.0, 0.0, 0.0], None)
    with pytest.raises(UserError, match=r"modes: u needs 0 values, got 1"):
        modes(task1, _known_model(), [0.0, 0.0], [1.0])


def test_an_undamped_pair_has_no_rounding_level_real_part():
    """An undamped pendulum's pair reads ± 5.78i, not 8.57e-17 ± 5.78i."""
    assert format_modes([[8.57e-17, 5.78], [8.57e-17, -5.78]]) == "± 5.78i"
    assert format_modes([[-0.01, 5.78], [-0.01, -5.78]]) == "-0.01 ± 5.78i"
