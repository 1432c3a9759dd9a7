"""learn._models: structured vs Hessian eq. 6, analytic systems, eq. 7, configs, vmap, tracing."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from known_fields import Field, MassField

from softpinn.errors import UserError
from softpinn.learn._models import (
    BlackBoxNet,
    HamiltonianNet,
    LagrangianHessianNet,
    LagrangianNet,
    ModelConfig,
    make_model,
)

G_ACC = 9.8


# --- analytic fields (known_fields.py holds their sub-network wrappers) -----------------------
# double pendulum, m = l = 1 (eq. 26), angles from the downward vertical
def dp_mass(q):
    c = jnp.cos(q[0] - q[1])
    return jnp.array([[2.0, c], [c, 1.0]])


def dp_mass_inv(q):
    c = jnp.cos(q[0] - q[1])
    return jnp.array([[1.0, -c], [-c, 2.0]]) / (2.0 - c**2)


def dp_potential(q):
    return -2.0 * G_ACC * jnp.cos(q[0]) - G_ACC * jnp.cos(q[1])


D_CONST = np.array([[0.3, 0.1], [0.1, 0.2]])
A_CONST = np.array([[1.0], [0.5]])


def dp_damping(q):
    return jnp.asarray(D_CONST) * (1.0 + 0.1 * jnp.sin(q[0]))


def dp_input(q):
    return jnp.asarray(A_CONST) * jnp.array([[1.0], [jnp.cos(q[1])]])


def dp_qdd_numpy(q, qd, u):
    """Hand-derived double pendulum with damping and input, solved by numpy."""
    s, c = np.sin(q[0] - q[1]), np.cos(q[0] - q[1])
    M = np.array([[2.0, c], [c, 1.0]])
    Cqd = np.array([s * qd[1] ** 2, -s * qd[0] ** 2])
    G = np.array([2 * G_ACC * np.sin(q[0]), G_ACC * np.sin(q[1])])
    D = D_CONST * (1.0 + 0.1 * np.sin(q[0]))
    A = A_CONST * np.array([[1.0], [np.cos(q[1])]])
    return np.linalg.solve(M, A @ u - Cqd - G - D @ qd)


def dp_fields(mass_fn):
    return dict(
        mass=MassField(mass_fn),
        potential=Field(dp_potential),
        damping=Field(dp_damping),
        input_map=Field(dp_input),
    )


def _states(key, n, m, k):
    kx, ku = jax.random.split(key)
    return jax.random.normal(kx, (k, 2 * n)), jax.random.normal(ku, (k, m))


# --- eq. 6: structured == Hessian form ---------------------------------------------------------
@pytest.mark.parametrize(
    "n,m,damping_form,activation",
    [(1, 0, "network", "softplus"), (3, 2, "constant", "tanh"), (6, 6, "none", "silu")],
)
def test_structured_lagrangian_equals_hessian_form(getkey, n, m, damping_form, activation):
    cfg = ModelConfig(
        kind="lagrangian",
        n=n,
        m=m,
        mass=(16, 2),
        potential=(16, 2),
        damping=(8, 1),
        input=(8, 1),
        damping_form=damping_form,
        activation=activation,
    )
    key = getkey()
    structured = make_model(cfg, key=key)
    hessian = make_model(
        ModelConfig.from_dict({**cfg.to_dict(), "kind": "lagrangian-hessian"}), key=key
    )
    assert isinstance(structured, LagrangianNet) and isinstance(hessian, LagrangianHessianNet)
    x, u = _states(getkey(), n, m, 5)
    a = jax.jit(jax.vmap(structured.vector_field))(x, u)
    b = jax.jit(jax.vmap(hessian.vector_field))(x, u)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-10)
    assert float(jnp.max(jnp.abs(a[:, n:]))) > 1e-3  # a non-trivial comparison


@pytest.mark.parametrize("cls", [LagrangianNet, LagrangianHessianNet])
def test_lagrangian_matches_analytic_double_pendulum(cls):
    model = cls(config=ModelConfig(kind="lagrangian", n=2, m=1), **dp_fields(dp_mass))
    rng = np.random.default_rng(3)
    qdd = jax.jit(model.qdd)
    for _ in range(4):
        q, qd, u = rng.normal(size=2), rng.normal(size=2), rng.normal(size=1)
        np.testing.assert_allclose(qdd(q, qd, u), dp_qdd_numpy(q, qd, u), rtol=1e-12, atol=1e-12)
    mats = model.matrices(jnp.array([0.3, -0.4]))
    np.testing.assert_allclose(mats["M"], dp_mass(jnp.array([0.3, -0.4])), atol=1e-14)
    np.testing.assert_allclose(mats["M"] @ mats["M_inv"], np.eye(2), atol=1e-12)
    np.testing.assert_allclose(
        mats["G"], [2 * G_ACC * np.sin(0.3), G_ACC * np.sin(-0.4)], atol=1e-12
    )


# --- eq. 7 -------------------------------------------------------------------------------------
def test_hamiltonian_matches_analytic_vector_field():
    model = HamiltonianNet(
        config=ModelConfig(kind="hamiltonian", n=2, m=1), **dp_fields(dp_mass_inv)
    )
    rng = np.random.default_rng(4)
    f = jax.jit(model.vector_field)
    for _ in range(4):
        q, p, u = rng.normal(size=2), rng.normal(size=2), rng.normal(size=1)
        s, c = np.sin(q[0] - q[1]), np.cos(q[0] - q[1])
        M = np.array([[2.0, c], [c, 1.0]])
        qdot = np.linalg.solve(M, p)
        # dH/dq = -1/2 qdot^T dM/dq qdot + dV/dq, dM/dq1 = -s [[0,1],[1,0]] = -dM/dq2
        dH_dq = np.array([s * qdot[0] * qdot[1], -s * qdot[0] * qdot[1]])
        dH_dq += [2 * G_ACC * np.sin(q[0]), G_ACC * np.sin(q[1])]
        D = D_CONST * (1.0 + 0.1 * np.sin(q[0]))
        A = A_CONST * np.array([[1.0], [np.cos(q[1])]])
        pdot = -dH_dq - D @ qdot + A @ u
        np.testing.assert_allclose(
            f(np.concatenate([q, p]), u), np.concatenate([qdot, pdot]), rtol=1e-12, atol=1e-12
        )
    mats = model.matrices(jnp.array([0.2, 0.1]))
    np.testing.assert_allclose(mats["M"], dp_mass(jnp.array([0.2, 0.1])), atol=1e-12)


def test_hamiltonian_and_lagrangian_agree_on_the_same_system():
    lag = LagrangianNet(config=ModelConfig(kind="lagrangian", n=2, m=1), **dp_fields(dp_mass))
    ham = HamiltonianNet(config=ModelConfig(kind="hamiltonian", n=2, m=1), **dp_fields(dp_mass_inv))
    q, qd, u = jnp.array([0.4, -1.1]), jnp.array([0.7, 0.2]), jnp.array([0.5])
    p = dp_mass(q) @ qd
    xl = lag.vector_field(jnp.concatenate([q, qd]), u)
    xh = ham.vector_field(jnp.concatenate([q, p]), u)
    np.testing.assert_allclose(xh[:2], qd, atol=1e-12)
    # pdot = d/dt (M qd) = Mdot qd + M qdd
    Mdot = jax.jvp(dp_mass, (q,), (qd,))[1]
    np.testing.assert_allclose(xh[2:], Mdot @ qd + dp_mass(q) @ xl[2:], atol=1e-12)


def test_hamiltonian_qdd_is_the_analytic_forward_dynamics(getkey):
    """HamiltonianNet.qdd at a velocity state: the hand-derived double pendulum's q̈ (Coriolis,
    damping and input included); for a random network, the derivative of its own velocity
    M⁻¹(q) p along its flow (central differences of RK4 steps)."""
    ham = HamiltonianNet(config=ModelConfig(kind="hamiltonian", n=2, m=1), **dp_fields(dp_mass_inv))
    rng = np.random.default_rng(7)
    for _ in range(3):
        q, qd, u = rng.normal(size=2), rng.normal(size=2), rng.normal(size=1)
        np.testing.assert_allclose(ham.qdd(q, qd, u), dp_qdd_numpy(q, qd, u), rtol=1e-11,
                                   atol=1e-11)
    net = make_model(ModelConfig(kind="hamiltonian", n=3, m=2, mass=(16, 2), potential=(16, 2)),
                     key=getkey())
    q, qd, u = jnp.array([0.3, -0.2, 0.5]), jnp.array([0.4, 0.1, -0.3]), jnp.array([0.2, -0.1])
    p = jnp.linalg.solve(net.matrices(q)["M_inv"], qd)
    x0, h = jnp.concatenate([q, p]), 1e-3

    def rk4(x, dt):
        f = lambda y: net.vector_field(y, u)
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    v = lambda x: net.vector_field(x, u)[:3]
    fd = (v(rk4(x0, h)) - v(rk4(x0, -h))) / (2 * h)
    np.testing.assert_allclose(v(x0), qd, atol=1e-12)
    np.testing.assert_allclose(net.qdd(q, qd, u), fd, rtol=1e-5, atol=1e-8)
    bb = make_model(ModelConfig(kind="blackbox", n=2, m=1), key=getkey())
    with pytest.raises(UserError, match="defined for Lagrangian .* and Hamiltonian"):
        bb.qdd(q[:2], qd[:2], u[:1])


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian"])
def test_power_balance_of_random_networks(getkey, kind):
    """dE/dt = q̇ᵀ (A u - D q̇) exactly: conservative when undamped and unforced."""
    n, m = 3, 2
    model = make_model(
        ModelConfig(kind=kind, n=n, m=m, mass=(16, 2), potential=(16, 2)), key=getkey()
    )
    x, u = _states(getkey(), n, m, 3)

    @jax.jit
    @jax.vmap
    def balance(xi, ui):
        xdot = model.vector_field(xi, ui)
        mats = model.matrices(xi[:n])
        v = xdot[:n]
        return jax.grad(model.energy)(xi) @ xdot, v @ (mats["A"] @ ui - mats["D"] @ v)

    dE, power = balance(x, u)
    np.testing.assert_allclose(dE, power, atol=1e-10)
    assert np.all(np.abs(power) > 1e-6)


# --- all kinds: shapes, dtypes, matrices -------------------------------------------------------
@pytest.mark.parametrize("kind", ["lagrangian", "lagrangian-hessian", "hamiltonian", "blackbox"])
@pytest.mark.parametrize("m", [0, 2])
def test_every_kind_builds_and_runs(getkey, kind, m):
    n = 2
    cfg = ModelConfig(kind=kind, n=n, m=m, mass=(8, 1), potential=(8, 1), hidden=(8, 1))
    model = make_model(cfg, key=getkey())
    x, u = _states(getkey(), n, m, 1)
    xdot = jax.jit(lambda x, u: model.vector_field(x, u))(x[0], u[0])
    assert xdot.shape == (2 * n,) and xdot.dtype == jnp.float64
    assert model.state_kind == ("momentum" if kind == "hamiltonian" else "velocity")
    if kind == "blackbox":
        with pytest.raises(UserError, match="no physical matrices"):
            model.matrices(x[0, :n])
        return
    mats = jax.jit(lambda q: model.matrices(q))(x[0, :n])
    assert mats["A"].shape == (n, m) and mats["G"].shape == (n,)
    for name in ("M", "M_inv", "D"):
        assert mats[name].shape == (n, n)
    assert np.all(np.linalg.eigvalsh(np.asarray(mats["M"])) > 0)
    # every physics model gives q̈ at a velocity state (a Hamiltonian one through p = M q̇)
    assert model.qdd(x[0, :n], x[0, n:], u[0]).shape == (n,)


def test_float32_models_have_float32_parameters_and_outputs(getkey):
    for kind in ("lagrangian", "hamiltonian", "blackbox"):
        cfg = ModelConfig(
            kind=kind, n=2, m=1, mass=(8, 1), potential=(8, 1), hidden=(8, 1), dtype="float32"
        )
        model = make_model(cfg, key=getkey())
        leaves = jax.tree_util.tree_leaves(eqx.filter(model, eqx.is_array))
        assert leaves and all(leaf.dtype == jnp.float32 for leaf in leaves)
        out = jax.jit(type(model).vector_field)(model, np.ones(4), np.ones(1))  # f64 cast
        assert out.dtype == jnp.float32


def test_blackbox_state_kind_and_input_concatenation(getkey):
    cfg = ModelConfig(kind="blackbox", n=2, m=1, hidden=(8, 1), state_kind="momentum")
    model = make_model(cfg, key=getkey())
    assert isinstance(model, BlackBoxNet) and model.state_kind == "momentum"
    x, u = jnp.arange(4.0), jnp.array([0.5])
    got = jax.jit(lambda x, u: (model.vector_field(x, u), model.mlp(jnp.append(x, u))))(x, u)
    np.testing.assert_allclose(got[0], got[1])


def test_vmap_equals_loop(getkey):
    cfg = ModelConfig(kind="lagrangian", n=3, m=1, mass=(16, 2), potential=(16, 2))
    model = make_model(cfg, key=getkey())
    x, u = _states(getkey(), 3, 1, 4)
    batched = jax.jit(jax.vmap(model.vector_field))(x, u)
    one = jax.jit(lambda x, u: model.vector_field(x, u))
    for k in range(4):
        np.testing.assert_allclose(batched[k], one(x[k], u[k]), atol=1e-13)


# --- config -------------------------------------------------------------------------------------
def test_config_json_round_trip():
    import json

    cfg = ModelConfig(
        kind="hamiltonian",
        n=3,
        m=0,
        mass=(32, 2),
        damping_form="constant",
        input_form="constant",
        eps=1e-2,
        dtype="float32",
        mass_init=150,
    )
    again = ModelConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg and hash(again) == hash(cfg)
    assert cfg.state_kind == "momentum"
    assert ModelConfig(kind="blackbox", n=1, m=0).state_kind == "velocity"


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"kind": "neural"}, "model kind must be one of"),
        ({"n": 0}, "model n must be an integer >= 1"),
        ({"m": -1}, "model m must be an integer >= 0"),
        ({"mass": (0, 2)}, "mass: must be"),
        ({"activation": "swish2"}, "activation: must be one of"),
        ({"damping_form": "rayleigh"}, "damping_form: must be one of"),
        ({"input_form": "table"}, "input_form: must be one of"),
        ({"eps": -1.0}, "eps: must be"),
        ({"eps": float("inf")}, "eps: must be a finite number >= 0, got inf"),
        ({"eps": float("nan")}, "eps: must be a finite number >= 0, got nan"),
        ({"mass_init": 0.0}, "mass_init: must be a number > 0"),
        ({"mass_init": float("nan")}, "mass_init: must be a number > 0"),
        ({"mass_init": True}, "mass_init: must be a number > 0"),
        ({"mass_init": 1e-8}, r"mass_init: must exceed eps² = 1e-06"),
        ({"dtype": "float16"}, "dtype: must be one of"),
        ({"state_kind": "momentum"}, "state_kind of a lagrangian model must be 'velocity'"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(UserError, match=match):
        ModelConfig(**{"kind": "lagrangian", "n": 2, "m": 1, **kwargs})


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian"])
def test_mass_init_sets_the_initial_diagonal(kind, getkey):
    """diag(L) = sqrt(mass_init) at the bias; at random q the diagonal of M (or M⁻¹) is near
    mass_init (the weights' random part is O(1) against sqrt(200) ≈ 14)."""
    cfg = ModelConfig(kind=kind, n=3, m=0, mass=(16, 2), mass_init=200.0)
    model = make_model(cfg, key=getkey())
    b = model.mass.mlp.biases[-1][:3]
    np.testing.assert_allclose(jax.nn.softplus(b) + cfg.eps, np.sqrt(200.0), rtol=1e-12)
    q = jax.random.uniform(getkey(), (50, 3), minval=-1, maxval=1)
    L = jax.vmap(model.mass.factor)(q)
    diag = np.einsum("bij,bij->bi", L, L)  # diag(L Lᵀ)
    assert 50 < np.median(diag) < 800
    plain = make_model(ModelConfig(kind=kind, n=3, m=0, mass=(16, 2)), key=getkey())
    L0 = jax.vmap(plain.mass.factor)(q)
    assert np.median(np.einsum("bij,bij->bi", L0, L0)) < 10


def test_config_from_dict_rejects_unknown_and_missing_keys():
    with pytest.raises(UserError, match=r"unknown model config key\(s\) \['width'\]"):
        ModelConfig.from_dict({"kind": "blackbox", "n": 1, "m": 0, "width": 3})
    with pytest.raises(UserError, match=r"missing key\(s\) \['m'\]"):
        ModelConfig.from_dict({"kind": "blackbox", "n": 1})


# --- jit: no recompilation on the second training-like step -----------------------------------
def test_second_jitted_step_does_not_retrace(getkey):
    model = make_model(
        ModelConfig(kind="lagrangian", n=2, m=1, mass=(8, 1), potential=(8, 1)), key=getkey()
    )

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def train_step(model, x, u, target):
        def loss(mdl):
            return jnp.mean((jax.vmap(mdl.vector_field)(x, u) - target) ** 2)

        val, grads = eqx.filter_value_and_grad(loss)(model)
        return val, eqx.apply_updates(model, jax.tree_util.tree_map(lambda g: -1e-3 * g, grads))

    for k in range(3):
        x, u = _states(getkey(), 2, 1, 8)
        val, model = train_step(model, x, u, jnp.full((8, 4), float(k)))
        assert np.isfinite(val)
