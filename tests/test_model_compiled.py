"""TrueModel's batched calls run compiled C (batched kernels from the code cache) at and above
COMPILE_FROM states, and give what CasADi's interpreter gives."""

from __future__ import annotations

import numpy as np
import pytest

from softpinn.symbolic import TrueModel
from softpinn.symbolic.model import _true_model as model_mod


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(3)
    n = 3
    return (rng.uniform(-1, 1, (model_mod.COMPILE_FROM, n)) * [1, 1, 0.2],
            rng.normal(size=(model_mod.COMPILE_FROM, n)),
            rng.normal(size=(model_mod.COMPILE_FROM, 3)))


def test_large_batches_run_compiled_and_agree(states, tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))
    q, qd, u = states
    fast, slow = TrueModel("task4"), TrueModel("task4", compiled=False)
    got, want = fast.qdd(q, qd, u), slow.qdd(q, qd, u)
    assert fast._kernels["forward"] is not None  # the batched kernel, not the interpreter
    assert fast._compiled == {} and slow._compiled == {} and slow._kernels == {}
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fast.M(q), slow.M(q), rtol=1e-12, atol=1e-14)
    e, g = fast.energy(q, qd), fast.hamiltonian(q, qd, u)
    assert e.shape == (len(q),) and [a.shape for a in g] == [q.shape, q.shape]
    np.testing.assert_allclose(e, slow.energy(q, qd), rtol=1e-12, atol=1e-14)
    for a, b in zip(g, slow.hamiltonian(q, qd, u), strict=True):  # qdot reaches ~1e4
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.max(np.abs(b)))
    assert fast.A(q).shape == slow.A(q).shape == (len(q), 3, 3)
    assert any((tmp_path / "cache").rglob("*.so"))


def test_a_function_without_a_kernel_runs_casadis_c(states, tmp_path, monkeypatch):
    from softpinn.symbolic.codegen import _kernel as kernel

    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))

    def no_kernel(*args, **kwargs):
        raise kernel.KernelError("no kernel")

    monkeypatch.setattr(kernel, "kernels", no_kernel)
    q, qd, u = states
    tm = TrueModel("task4")
    np.testing.assert_allclose(tm.qdd(q, qd, u), TrueModel("task4", compiled=False).qdd(q, qd, u),
                               rtol=1e-12, atol=1e-12)
    assert tm._kernels["forward"] is None
    assert tm._compiled["forward"].class_name() == "External"


def test_small_batches_and_single_states_stay_interpreted(states):
    q, qd, u = states
    tm = TrueModel("task4")
    tm.qdd(q[:5], qd[:5], u[:5])
    tm.qdd(q[0], qd[0], u[0])
    assert tm._compiled == {}


def test_without_compiler_falls_back_with_a_warning(states, tmp_path, monkeypatch):
    from softpinn.symbolic.codegen import _codegen as codegen
    from softpinn.symbolic.codegen import _kernel as kernel

    monkeypatch.setattr(codegen, "find_compiler", lambda compiler=None: None)
    monkeypatch.setattr(kernel, "find_compiler", lambda compiler=None: None)
    monkeypatch.setattr(codegen, "_warned", set())
    q, qd, u = states
    tm = TrueModel("task4", compiled=True)
    with pytest.warns(codegen.CompilerWarning, match="no C compiler"):
        got = tm.qdd(q, qd, u)
    np.testing.assert_allclose(got, TrueModel("task4", compiled=False).qdd(q, qd, u), rtol=0)
