"""The JAX RK4 simulation of the exact model (softpinn.bridge.exact.simulate / make_dataset):
the same trajectories as CasADi's rk4 path to rounding, cvodes' to the step's accuracy, and
data sets in the format of ``softpinn simulate``."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from softpinn.bridge.exact import jax_model, make_dataset, simulate
from softpinn.symbolic import load_spec
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._datasets import (
    data_config,
    draw_trajectories,
    read_dataset,
    write_dataset,
)
from softpinn.symbolic.simulation._datasets import make_dataset as casadi_dataset
from softpinn.symbolic.simulation._simulate import (
    SimulationConfig,
    SimulationError,
    SingularityError,
)
from softpinn.symbolic.simulation._simulate import simulate as casadi_simulate

jax.config.update("jax_enable_x64", True)


def _draw(name, k, duration):
    spec = load_spec(name)
    return draw_trajectories(data_config(spec), spec.n, spec.m, list(range(k)),
                             duration=duration)


@pytest.mark.parametrize("backend", ["jax", "c"])
@pytest.mark.parametrize(("name", "dt", "cvodes_tol"), [("task1", 0.002, 1e-8),
                                                      ("task4", 0.001, 1e-4)])
def test_rk4_equals_casadi_rk4_and_cvodes_to_the_step(name, dt, cvodes_tol, backend):
    x0, sigs = _draw(name, 3, 1.0)
    rk4 = SimulationConfig(integrator="rk4", duration=1.0, rate=50.0, dt=dt)
    got = simulate(jax_model(name), x0, sigs, rk4, backend=backend)
    assert got.info["backend"] == backend
    ref = casadi_simulate(functions(name), x0, sigs, rk4)
    assert got.x.shape == ref.x.shape == (3, 50, 2 * load_spec(name).n)
    np.testing.assert_array_equal(got.t, ref.t)
    np.testing.assert_array_equal(got.u, ref.u)
    for key in ("x", "qdd", "p"):
        a, b = getattr(got, key), getattr(ref, key)
        assert np.max(np.abs(a - b)) <= 1e-10 * max(1.0, np.max(np.abs(b))), key
    cv = casadi_simulate(functions(name), x0, sigs,
                         SimulationConfig(integrator="cvodes", duration=1.0, rate=50.0))
    assert np.max(np.abs(got.x - cv.x)) <= cvodes_tol
    assert np.max(np.abs(got.x - cv.x)) > 0
    assert got.info["max_mass_condition"] >= 1.0


@pytest.mark.parametrize("backend", ["jax", "c"])
def test_dataset_has_the_simulate_format(tmp_path, backend):
    opts = dict(trajectories=2, duration=0.5, rate=50.0, dt=0.01, integrator="rk4")
    got = make_dataset("task3", backend=backend, **opts)
    ref = casadi_dataset("task3", compile=False, **opts)
    assert set(got.meta) - {"jax_version"} == set(ref.meta)
    for key in ("t", "q", "qd", "qdd", "p", "u", "traj"):
        a, b = getattr(got, key), getattr(ref, key)
        assert a.shape == b.shape and a.dtype == b.dtype, key
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11, err_msg=key)
    for key in ("initial_states", "signals", "splits", "n", "m", "rate", "spec", "seed"):
        assert got.meta[key] == ref.meta[key], key
    if backend == "jax":
        assert got.meta["compiled"] == "jax" and "JAX" in got.meta["simulation"]["method"]
    else:
        assert got.meta["compiled"] == "c-kernel" and "C kernels" in got.meta["simulation"][
            "method"]
    back = read_dataset(write_dataset(tmp_path / "d.npz", got))
    np.testing.assert_array_equal(back.q, got.q)
    assert back.meta["simulation"] == got.meta["simulation"]


def test_auto_backend_is_c_on_the_cpu_with_a_compiler_else_jax(monkeypatch):
    from softpinn.bridge.exact.simulate import choose_backend
    from softpinn.symbolic.codegen import _kernel as kernel

    assert choose_backend("auto") == ("c" if jax.default_backend() == "cpu" else "jax")
    monkeypatch.setattr(kernel, "find_compiler", lambda compiler=None: None)
    assert choose_backend("auto") == "jax"
    with pytest.raises(SimulationError, match="backend: expected one of auto, c, jax"):
        choose_backend("gpu")


@pytest.mark.parametrize("backend", ["jax", "c"])
def test_errors_name_the_problem(backend):
    em = jax_model("task1")
    x0, sigs = _draw("task1", 2, 1.0)
    cfg = SimulationConfig(integrator="rk4", duration=0.2, rate=50.0)
    with pytest.raises(SimulationError, match="integrator: the JAX path integrates with 'rk4'"):
        simulate(em, x0, sigs, SimulationConfig(integrator="cvodes"), backend=backend)
    with pytest.raises(SimulationError, match="expected 4 values per trajectory"):
        simulate(em, x0[:, :3], sigs, cfg, backend=backend)
    with pytest.raises(SimulationError, match="expected one per trajectory"):
        simulate(em, x0, sigs[:1], cfg, backend=backend)
    with pytest.raises(SingularityError, match="trajectory 1: the state is not finite"):
        simulate(em, x0 * [[1.0], [1e308]], sigs, cfg, backend=backend)


def test_simulate_cli_integrator_jax_rk4(tmp_path, capsys):
    """`softpinn simulate --integrator jax-rk4` writes the CasADi rk4 file's data (to rounding)."""
    from softpinn.bridge.cli import main
    from softpinn.symbolic.simulation._datafile import read_dataset

    args = ["simulate", "task1", "--trajectories", "2", "--duration", "0.5", "--rate", "50",
            "--quiet", "--no-compile"]
    assert main([*args, "--integrator", "jax-rk4", "--out", str(tmp_path / "j.npz")]) == 0
    assert "rk4 in JAX" in capsys.readouterr().out  # --no-compile: XLA, no C compiler
    assert main([*args, "--integrator", "rk4", "--out", str(tmp_path / "c.npz")]) == 0
    j, c = read_dataset(tmp_path / "j.npz"), read_dataset(tmp_path / "c.npz")
    assert j.meta["compiled"] == "jax" and "JAX" in j.meta["simulation"]["method"]
    for key in ("q", "qd", "u"):
        np.testing.assert_allclose(getattr(j, key), getattr(c, key), rtol=0, atol=1e-12)
    # with a compiler: the batched C kernels, the same data
    args = [a for a in args if a != "--no-compile"]
    assert main([*args, "--integrator", "jax-rk4", "--out", str(tmp_path / "k.npz")]) == 0
    assert "rk4 in batched C kernels" in capsys.readouterr().out
    k = read_dataset(tmp_path / "k.npz")
    assert k.meta["compiled"] == "c-kernel"
    for key in ("q", "qd", "u"):
        np.testing.assert_allclose(getattr(k, key), getattr(c, key), rtol=0, atol=1e-12)
