"""An exact model's functions replayed without CasADi (learn/_sx_replay.py): the data written by
bridge.exact.serialize, run by ProgramFunction in JAX, equal CasADi's compiled values to 1e-12
(theta = 0 of the delta parameterization included), batched, in float32, with several inputs
and outputs; bad data and bad calls get one-line errors."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.bridge.exact.serialize import function_data
from softpinn.errors import UserError
from softpinn.learn._sx_replay import ProgramFunction
from softpinn.symbolic import TrueModel

jax.config.update("jax_enable_x64", True)


def _states(n, m, count=6, seed=3):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.3, 0.3, (count, n))
    q[0] = 0.0  # straight: theta = 0 of the delta parameterization
    return q, rng.uniform(-0.5, 0.5, (count, n)), rng.uniform(-1, 1, (count, m))


def test_task5_forward_dynamics_and_the_hamiltonian_field_replay_exactly():
    tm = TrueModel("task5")
    q, qd, u = _states(tm.n, tm.m)
    # through JSON text, as a file on a machine without CasADi would carry it
    f = ProgramFunction(json.loads(json.dumps(function_data(tm.functions["forward"]))))
    assert f.name_in == ("q", "qd", "u") and f.name_out == ("qdd",)
    # batched without jit: compiling 10,013 instructions costs 30 s on 2 cores; jit is tested
    # on a smaller program below (and the translation's jit path in test_exact_translate.py)
    got = jax.vmap(lambda *a: f(*a)[0][:, 0])(q, qd, u)
    ref = np.asarray(tm.qdd(q, qd, u))
    scale = max(1.0, float(np.abs(ref).max()))
    assert np.abs(np.asarray(got) - ref).max() <= 1e-12 * scale
    h = ProgramFunction(function_data(tm.functions["hamiltonian"]))  # two outputs
    qdot, pdot = h(q[1], qd[1], u[1])
    ref = [np.asarray(v).ravel() for v in tm.functions["hamiltonian"](q[1], qd[1], u[1])]
    assert np.allclose(qdot[:, 0], ref[0], rtol=0, atol=1e-12)
    assert np.allclose(pdot[:, 0], ref[1], rtol=0, atol=1e-12)
    low = f(*(jnp.asarray(a[2], jnp.float32) for a in (q, qd, u)))[0]  # float32 in, float32 out
    assert low.dtype == jnp.float32
    assert np.allclose(low[:, 0], tm.qdd(q[2], qd[2], u[2]), rtol=1e-3, atol=1e-3)


def test_a_matrix_output_is_dense_and_gradients_flow():
    tm = TrueModel("task4")
    f = ProgramFunction(function_data(tm.functions["M"]))
    q = np.array([0.2, -0.1, 0.05])
    M = f(q)[0]
    assert M.shape == (tm.n, tm.n) and np.allclose(M, np.asarray(tm.functions["M"](q)), atol=1e-14)
    g = jax.jit(jax.grad(lambda x: jnp.trace(f(x)[0])))(jnp.asarray(q))
    h = 1e-6
    fd = [(np.trace(np.asarray(tm.functions["M"](q + h * e))) -
           np.trace(np.asarray(tm.functions["M"](q - h * e)))) / (2 * h) for e in np.eye(3)]
    assert np.allclose(g, fd, rtol=1e-6, atol=1e-8)


def test_bad_data_and_bad_calls_are_refused_in_one_line():
    tm = TrueModel("task1")
    data = function_data(tm.functions["forward"])
    f = ProgramFunction(data)
    with pytest.raises(UserError, match=r"takes 3 inputs \['q', 'qd', 'u'\], got 2"):
        f(np.zeros(1), np.zeros(1))
    with pytest.raises(UserError, match=f"input qd has {tm.n} values, got {tm.n + 1}"):
        f(np.zeros(tm.n), np.zeros(tm.n + 1), np.zeros(tm.m))
    with pytest.raises(UserError, match="expected program data of format"):
        ProgramFunction({"format": "other", "name": "x"})
    bad = dict(data, code=[*data["code"], ["WARP", [0], [1], None]])
    with pytest.raises(UserError, match="unknown operation 'WARP'"):
        ProgramFunction(bad)
    bad = dict(data, code=[["INPUT", [7, 0], [0], None]])  # an input that does not exist
    with pytest.raises(UserError, match=r"instruction 0 \(INPUT\) has bad indices"):
        ProgramFunction(bad)
