"""The Functions contract: keys, named inputs/outputs, C-identifier names, shapes, caching,
and that every Function can be written out as C."""

from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic import load_spec
from softpinn.symbolic.model._functions import SIGNATURES, function_sizes, functions, safe_name
from softpinn.symbolic.spec._spec import preset_path


@pytest.mark.parametrize("name", ["task1", "task2", "task3", "task4", "task5"])
def test_signatures(name):
    spec = load_spec(name)
    fns = functions(name)
    assert set(fns) == set(SIGNATURES)
    n, m = spec.n, spec.m
    sizes = {"q": n, "qd": n, "u": m, "qdd": n, "p": n, "x": 2 * n}
    out_shapes = {"M": (n, n), "M_inv": (n, n), "G": (n, 1), "D": (n, n), "A": (n, m),
                  "C": (n, n), "Cqd": (n, 1), "qdd": (n, 1), "tau": (n, 1), "E": (1, 1),
                  "T": (1, 1), "V": (1, 1), "p": (n, 1), "qdot": (n, 1), "pdot": (n, 1),
                  "xdot": (2 * n, 1)}
    for key, f in fns.items():
        ins, outs = SIGNATURES[key]
        assert f.name() == f"{name}_{key}"
        assert re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", f.name())
        assert f.name_in() == list(ins) and f.name_out() == list(outs)
        for i, nm in enumerate(ins):
            assert f.size_in(i) == (sizes[nm], 1), (key, nm)
        for j, nm in enumerate(outs):
            assert f.size_out(j) == out_shapes[nm], (key, nm)
            assert f.sparsity_out(j).is_dense()


def test_cached_per_spec_value(tmp_path):
    a = functions("task4")
    assert functions(load_spec("task4"))["forward"] is a["forward"]
    a["forward"] = None  # the caller's dict is a copy
    assert functions("task4")["forward"] is not None
    path = tmp_path / "my arm-1.toml"
    path.write_text(preset_path("task4").read_text().replace('name = "task4"', 'name = "1 my-arm"'))
    fns = functions(path)
    assert fns["M"].name() == "m_1_my_arm_M" == f"{safe_name('1 my-arm')}_M"


def test_forward_and_ode_agree_and_generate_c(tmp_path):
    fns = functions("task5")
    rng = np.random.default_rng(0)
    q, qd, u = rng.uniform(-0.4, 0.4, 6), rng.normal(size=6), rng.normal(size=6)
    qdd = np.array(fns["forward"](q, qd, u)).ravel()
    xdot = np.array(fns["ode"](np.concatenate([q, qd]), u)).ravel()
    np.testing.assert_array_equal(xdot, np.concatenate([qd, qdd]))
    cg = ca.CodeGenerator("task5_all.c")
    for f in fns.values():
        cg.add(f)
    source = cg.dump()
    assert "task5_forward" in source and "task5_hamiltonian" in source


def test_sizes_are_reported():
    sizes = function_sizes(functions("task4"))
    assert sizes["forward"] > sizes["M"] > 0
