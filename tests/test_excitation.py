"""The inertial share of a data set's forces along the true M's eigenvectors, against task 1's
closed form (two masses on springs, M = diag(1, 1.8)), and the bad-input message."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.bridge.analysis.excitation import inertial_share
from softpinn.symbolic.model import TrueModel
from softpinn.symbolic.spec import load_spec

# task1.toml: masses 1.0 and 1.8; k1 = 2.1 between the masses, k2 = 4.6 to the ground;
# b = 0.3 between the masses
M = np.diag([1.0, 1.8])
K = np.array([[2.1, -2.1], [-2.1, 2.1 + 4.6]])
B = 0.3 * np.array([[1.0, -1.0], [-1.0, 1.0]])


def test_task1_closed_form():
    rng = np.random.default_rng(0)
    q, qd = rng.normal(size=(200, 2)), rng.normal(size=(200, 2))
    u = np.zeros((200, 0))
    out = inertial_share(TrueModel(load_spec("task1")), q, qd, u)
    # M is diagonal: its eigenvectors are the coordinates, the lighter (1.0) first
    np.testing.assert_allclose(out["eigenvalue"], [1.0, 1.8], rtol=1e-12)
    inertial = -(q @ K.T) - qd @ B.T  # M q̈ = -K q - B q̇
    damping = qd @ B.T

    def rms(a):
        return np.sqrt(np.mean(a * a, axis=0))

    # an eigenvector's sign is free; rms does not see it
    np.testing.assert_allclose(out["inertial"], rms(inertial), rtol=1e-9)
    np.testing.assert_allclose(out["damping"], rms(damping), rtol=1e-9)
    np.testing.assert_allclose(out["rest"], rms(q @ K.T), rtol=1e-9)  # A u - G - C q̇ = -K q
    np.testing.assert_allclose(out["inertia_over_damping"], rms(inertial) / rms(damping),
                               rtol=1e-9)


def test_rows_must_agree():
    with pytest.raises(ValueError, match=r"q, qd, u: expected the same number N > 0 of rows, "
                                         r"got 3, 2, 3"):
        inertial_share(TrueModel(load_spec("task1")), np.zeros((3, 2)), np.zeros((2, 2)),
                       np.zeros((3, 0)))
