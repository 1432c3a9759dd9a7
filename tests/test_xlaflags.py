"""XLA's fast-compile settings (learn/xlaflags.py): added to XLA_FLAGS without overriding what
a user set, and never once JAX's backend exists (XLA has read its flags then)."""

from __future__ import annotations

import os
import subprocess
import sys

import jax.numpy as jnp
import pytest

from softpinn.learn.xlaflags import FAST_COMPILE, use_fast_compile, with_fast_compile


def test_flags_are_added_and_a_users_own_setting_is_kept():
    assert with_fast_compile(None).split() == list(FAST_COMPILE)
    mine = "--xla_force_host_platform_device_count=4 --xla_backend_optimization_level=2"
    words = with_fast_compile(mine).split()
    assert words[:2] == mine.split()  # the user's flags first, untouched
    assert "--xla_backend_optimization_level=0" not in words  # the user's level wins
    assert "--xla_cpu_use_fusion_emitters=false" in words
    assert with_fast_compile(with_fast_compile(None)) == with_fast_compile(None)  # idempotent


def test_an_environment_is_given_the_flags_and_a_started_backend_is_left_alone(monkeypatch):
    env = {"XLA_FLAGS": "--xla_dump_to=/tmp/x"}
    assert use_fast_compile(env) and env["XLA_FLAGS"].startswith("--xla_dump_to=/tmp/x ")
    jnp.zeros(1).block_until_ready()  # this process's backend exists
    monkeypatch.setenv("XLA_FLAGS", "")
    assert not use_fast_compile()
    assert os.environ["XLA_FLAGS"] == ""


def test_a_new_process_compiles_with_the_flags_and_computes_the_same():
    """The same program in a process with and without the flags: equal to rounding in float64
    (no fast-math), so quick runs and tests lose nothing but run time."""
    code = ("import sys; from softpinn.learn.xlaflags import use_fast_compile\n"
            "if sys.argv[1] == 'fast': assert use_fast_compile()\n"
            "import jax, jax.numpy as jnp; jax.config.update('jax_enable_x64', True)\n"
            "x = jnp.linspace(0.1, 3.0, 1001)\n"
            "f = jax.jit(lambda x: jnp.sum(jnp.tanh(x) * jnp.exp(-x) / (1 + x**2)))\n"
            "print(repr(float(f(x))), repr(float(jax.grad(f)(x)[7])))\n")
    env = dict(os.environ, XLA_FLAGS="")
    out = {mode: subprocess.run([sys.executable, "-c", code, mode], env=env, capture_output=True,
                                text=True, timeout=300, check=True).stdout.split()
           for mode in ("fast", "default")}
    for fast, default in zip(out["fast"], out["default"], strict=True):
        assert float(fast) == pytest.approx(float(default), rel=1e-13, abs=0)
