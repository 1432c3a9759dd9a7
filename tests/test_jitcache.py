"""The persistent cache of XLA's compiled programs (learn/jitcache.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from softpinn.learn import jitcache


def test_folder_follows_the_environment(tmp_path):
    key = jitcache.cache_folder({"SOFTPINN_JIT_CACHE": str(tmp_path)}).name
    assert len(key) == 16 and int(key, 16) >= 0  # the machine's hash
    assert jitcache.cache_folder({"SOFTPINN_JIT_CACHE": str(tmp_path)}) == tmp_path / key
    assert jitcache.cache_folder({"SOFTPINN_CACHE": str(tmp_path)}) == tmp_path / "jax" / key
    home = jitcache.cache_folder({})
    assert home.parent == jitcache.Path.home() / ".cache" / "softpinn" / "jax"
    for off in ("off", "0", "OFF", "none", ""):
        assert jitcache.cache_folder({"SOFTPINN_JIT_CACHE": off}) is None


def test_enable_sets_jax_variables_and_keeps_a_users_folder(tmp_path):
    env = {"SOFTPINN_JIT_CACHE": str(tmp_path)}
    folder = jitcache.cache_folder(env)
    folder.mkdir(parents=True)
    (folder / "probe.json").write_text(json.dumps({"ok": True}))  # no subprocess here
    assert jitcache.enable_compile_cache(env) == folder
    assert env["JAX_COMPILATION_CACHE_DIR"] == str(folder)
    assert int(env["JAX_COMPILATION_CACHE_MAX_SIZE"]) == jitcache.MAX_BYTES
    mine = {"JAX_COMPILATION_CACHE_DIR": "/somewhere/of/mine", "SOFTPINN_JIT_CACHE": "x"}
    assert str(jitcache.enable_compile_cache(mine)) == "/somewhere/of/mine"
    assert "JAX_COMPILATION_CACHE_MAX_SIZE" not in mine


def test_enable_turns_itself_off_where_it_cannot_work(tmp_path):
    off = {"SOFTPINN_JIT_CACHE": "off"}
    assert jitcache.enable_compile_cache(off) is None and "JAX_COMPILATION_CACHE_DIR" not in off
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    env = {"SOFTPINN_JIT_CACHE": str(blocked)}  # a folder cannot be made under a file
    assert jitcache.enable_compile_cache(env) is None and "JAX_COMPILATION_CACHE_DIR" not in env
    env = {"SOFTPINN_JIT_CACHE": str(tmp_path / "rejecting")}
    folder = jitcache.cache_folder(env)
    folder.mkdir(parents=True)
    (folder / "probe.json").write_text(json.dumps({"ok": False, "why": "XLA rejected it"}))
    assert jitcache.enable_compile_cache(env) is None and "JAX_COMPILATION_CACHE_DIR" not in env


def _rejected(folder) -> bool:
    """Whether the probe found that this machine's XLA rejects its own cached programs
    (jax-ml/jax#38445: some Intel CPUs); the cache is then off, which the tests check instead."""
    record = json.loads((folder / "probe.json").read_text())
    return record["ok"] is False and record["why"].startswith("XLA did not load")


def test_probe_loads_a_cached_program_and_remembers(tmp_path):
    folder = tmp_path / "machine"
    ok = jitcache.probe(folder)
    record = json.loads((folder / "probe.json").read_text())
    assert record["ok"] is ok and (ok or _rejected(folder))
    assert [p.name for p in folder.iterdir()] == ["probe.json"]  # its programs removed
    (folder / "probe.json").write_text(json.dumps({"ok": False}))
    assert jitcache.probe(folder) is False  # read back, not probed again


def test_a_probe_that_cannot_run_keeps_no_answer(tmp_path, monkeypatch):
    monkeypatch.setattr(jitcache.sys, "executable", "/bin/false")  # every subprocess fails
    assert jitcache.probe(tmp_path / "machine") is False
    assert not (tmp_path / "machine" / "probe.json").exists()  # asked again next time


_PROGRAM = r"""
import jax, jax.numpy as jnp, numpy as np, sys
jax.config.update("jax_enable_x64", True)
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
x = jnp.linspace(0.0, 1.0, 7)
y = jax.jit(lambda x: jnp.tanh(jnp.outer(x, x)).sum(0) ** 3)(x)
print(int("/jax/compilation_cache/cache_hits" in events), repr(np.asarray(y).tobytes().hex()))
"""


def test_a_second_process_loads_the_first_ones_program(tmp_path):
    env = {**os.environ, "SOFTPINN_JIT_CACHE": str(tmp_path), "JAX_PLATFORMS": "cpu",
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    folder = jitcache.enable_compile_cache(env)
    if folder is None:  # a machine whose XLA rejects its cached programs: the cache stays off
        assert _rejected(jitcache.cache_folder(env)) and "JAX_COMPILATION_CACHE_DIR" not in env
        return
    assert env["JAX_COMPILATION_CACHE_DIR"] == str(folder)
    runs = [subprocess.run([sys.executable, "-c", _PROGRAM], env=env, capture_output=True,
                           text=True, timeout=120, check=True).stdout.split() for _ in range(2)]
    assert [r[0] for r in runs] == ["0", "1"]  # compiled, then loaded from the cache
    assert runs[0][1] == runs[1][1]  # the same numbers, bit for bit
    assert len(list(folder.glob("jit__lambda-*-cache"))) == 1  # one entry, read twice


def test_cli_commands_that_compile_turn_the_cache_on(tmp_path, monkeypatch, capsys):
    from softpinn.bridge import cli

    seen = []
    monkeypatch.setattr(jitcache, "enable_compile_cache", lambda: seen.append(1))
    missing = str(tmp_path / "missing.npz")
    assert cli.main(["train", missing, "--model", "lagrangian", "--out", str(tmp_path / "r")]) == 2
    assert seen == [1]
    assert cli.main(["derive", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "d")]) == 2
    assert seen == [1]  # deriving compiles no JAX program: no probe, no cache
    assert "error" in capsys.readouterr().err


_LATE = r"""
import jax, jax.numpy as jnp
jax.jit(lambda x: x + 1.0)(1.0)  # a compilation before the cache is turned on
from softpinn.learn.jitcache import enable_compile_cache
print(enable_compile_cache())
jax.jit(lambda x: jnp.tanh(x) * 3.0)(jnp.ones(3))
"""


def test_turned_on_after_a_first_compilation(tmp_path):
    """A process that compiled before turning the cache on still writes to it (JAX opens its
    cache at the first compilation after a folder is set)."""
    env = {**os.environ, "SOFTPINN_JIT_CACHE": str(tmp_path), "JAX_PLATFORMS": "cpu",
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", _LATE], env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    if out[-1] == "None":  # a machine whose XLA rejects its cached programs: the cache stays off
        assert _rejected(jitcache.cache_folder({"SOFTPINN_JIT_CACHE": str(tmp_path)}))
        return
    folder = jitcache.Path(out[-1])
    assert folder.parent == tmp_path and list(folder.glob("jit__lambda-*-cache"))


def test_a_folder_given_to_jax_in_this_process_is_kept(tmp_path, monkeypatch):
    import jax

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("SOFTPINN_JIT_CACHE", str(tmp_path / "ours"))
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "theirs"))
    try:
        assert jitcache.enable_compile_cache() == tmp_path / "theirs"
        assert "JAX_COMPILATION_CACHE_DIR" not in os.environ and not (tmp_path / "ours").exists()
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_a_machine_that_rejects_its_programs_turns_the_cache_off(tmp_path, monkeypatch):
    monkeypatch.setattr(jitcache, "_PROBE", "print(0)")  # the second process finds nothing
    env = {"SOFTPINN_JIT_CACHE": str(tmp_path)}
    assert jitcache.enable_compile_cache(env) is None and "JAX_COMPILATION_CACHE_DIR" not in env
    assert _rejected(jitcache.cache_folder(env))  # kept: the next process does not probe again
