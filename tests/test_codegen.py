"""Generated C: agreement with the SX/MX functions, the cache, the compiler fallback, timeouts."""

from __future__ import annotations

import json
import stat
import time
import warnings

import casadi as ca
import numpy as np
import pytest

from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.codegen._generate import generate


def toy_functions(tag: str = "toy") -> dict[str, ca.Function]:
    """An SX function and an MX graph that maps an SX function (the structure the EOM use)."""
    q = ca.SX.sym("q", 3)
    qd = ca.SX.sym("qd", 3)
    M = ca.SX.eye(3) * (2 + ca.sin(q[0]) ** 2) + ca.mtimes(q, q.T) * 0.1
    fM = ca.Function(f"{tag}_M", [q], [M], ["q"], ["M"], {"cse": True})
    z = ca.SX.sym("zeta")
    w = ca.SX.sym("w")
    dens = ca.Function(
        f"{tag}_density",
        [q, qd, z, w],
        [w * ca.exp(z * q[1]) * ca.dot(qd, qd)],
        ["q", "qd", "zeta", "w"],
        ["T"],
    )
    mapped = dens.map(f"{tag}_map", "serial", 5, [0, 1], [0])
    qm, qdm = ca.MX.sym("q", 3), ca.MX.sym("qd", 3)
    nodes = ca.DM(np.linspace(0.1, 0.9, 5)).T
    weights = ca.DM(np.full(5, 0.2)).T
    T = mapped(qm, qdm, nodes, weights)
    fT = ca.Function(
        f"{tag}_kinetic", [qm, qdm], [T + ca.mtimes(fM(qm), qdm)[0]], ["q", "qd"], ["T"]
    )
    return {"M": fM, "kinetic": fT}


def test_compiled_agrees_with_virtual_machine(tmp_path):
    fns = toy_functions()
    res = codegen.compile_functions(fns, directory=tmp_path)
    assert res.compiled and not res.from_cache
    assert res.library.is_file() and res.library.parent.parent == tmp_path
    rng = np.random.default_rng(0)
    for key, fn in fns.items():
        ext = res.functions[key]
        assert ext.name() == fn.name()
        assert ext.name_in() == fn.name_in() and ext.name_out() == fn.name_out()
        for _ in range(5):
            args = [rng.normal(size=fn.size_in(i)) for i in range(fn.n_in())]
            np.testing.assert_allclose(
                np.asarray(ext(*args)), np.asarray(fn(*args)), rtol=1e-12, atol=1e-12
            )


def test_cache_hit_on_second_call(tmp_path):
    fns = toy_functions("cachetoy")
    first = codegen.compile_functions(fns, directory=tmp_path)
    mtime = first.library.stat().st_mtime_ns
    second = codegen.compile_functions(toy_functions("cachetoy"), directory=tmp_path)
    assert second.from_cache and second.key == first.key
    assert second.library == first.library
    assert second.library.stat().st_mtime_ns == mtime
    # another flag set or other functions give another library
    third = codegen.compile_functions(fns, directory=tmp_path, flags=("-O0", "-fPIC", "-shared"))
    assert not third.from_cache and third.key != first.key
    assert codegen.content_hash(toy_functions("other")) != codegen.content_hash(fns)
    # no temporary files or build directories left behind
    assert not [p for p in tmp_path.rglob("*.tmp")]
    assert not list(tmp_path.rglob(".build-*"))


def test_concurrent_compiles_of_the_same_functions(tmp_path):
    """Two compiles of one key at once both succeed (private build directories, atomic install)."""
    from concurrent.futures import ThreadPoolExecutor

    fns = toy_functions("race")
    with ThreadPoolExecutor(2) as pool:
        results = list(
            pool.map(lambda _: codegen.compile_functions(fns, directory=tmp_path), range(2))
        )
    assert results[0].library == results[1].library and results[0].library.is_file()
    q = np.array([0.1, 0.2, 0.3])
    for r in results:
        np.testing.assert_allclose(
            np.asarray(r.functions["M"](q)), np.asarray(fns["M"](q)), rtol=1e-12
        )
    assert not list(tmp_path.rglob(".build-*"))


def test_cache_dir_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "env-cache"))
    assert codegen.cache_dir() == tmp_path / "env-cache"
    assert codegen.cache_dir(tmp_path / "arg") == tmp_path / "arg"
    monkeypatch.delenv("SOFTPINN_CACHE")
    assert codegen.cache_dir() == (codegen.Path.home() / ".cache" / "softpinn")


def test_missing_compiler_falls_back_with_one_warning(tmp_path):
    fns = toy_functions("nocc")
    missing = str(tmp_path / "no-such-compiler")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out1 = codegen.compiled(fns, directory=tmp_path, compiler=missing)
        out2 = codegen.compiled(fns, directory=tmp_path, compiler=missing)
    relevant = [w for w in caught if issubclass(w.category, codegen.CompilerWarning)]
    assert len(relevant) == 1
    assert "no C compiler" in str(relevant[0].message)
    assert out1["M"] is fns["M"] and out2["kinetic"] is fns["kinetic"]
    assert not list(tmp_path.rglob("*.so"))
    with pytest.raises(codegen.CompilerError, match="no C compiler"):
        codegen.compile_functions(fns, compiler=missing, fallback=False)


def test_compiler_timeout_kills_process_group(tmp_path):
    """A hanging compiler and its children (cc1) are killed at the timeout."""
    pidfile = tmp_path / "child.pid"
    script = tmp_path / "slowcc"
    script.write_text(f"#!/bin/sh\nsleep 30 &\necho $! > {pidfile}\nwait\n")
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    start = time.perf_counter()
    with pytest.raises(codegen.CompilerError, match="timeout"):
        codegen.compile_functions(
            toy_functions("slow"), directory=tmp_path, compiler=str(script), timeout=0.5
        )
    assert time.perf_counter() - start < 10
    child = int(pidfile.read_text())
    time.sleep(0.2)
    assert _gone_or_zombie(child)
    assert not list(tmp_path.rglob("*.so"))


def _gone_or_zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            state = fh.read().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return True
    return state in ("Z", "X")


def test_compiler_failure_is_one_line(tmp_path):
    script = tmp_path / "badcc"
    script.write_text("#!/bin/sh\necho 'fatal: broken' >&2\nexit 3\n")
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    with pytest.raises(codegen.CompilerError, match=r"exit 3\): fatal: broken"):
        codegen.compile_functions(toy_functions("bad"), directory=tmp_path, compiler=str(script))


def test_generate_writes_source_library_casadi_files_and_summary(tmp_path):
    fns = toy_functions("gen")
    summary = generate(
        fns, tmp_path / "out", timings={"functions": 0.5}, cache=tmp_path / "cache"
    )
    # the library is installed in the cache too: compiling the same functions is a cache hit
    assert codegen.compile_functions(fns, directory=tmp_path / "cache").from_cache
    out = tmp_path / "out"
    assert (out / "softpinn_eom.c").is_file() and (out / "softpinn_eom.so").is_file()
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk == summary
    assert set(summary["timings_s"]) == {"functions", "generate_c", "compile"}
    q = np.array([0.3, -0.2, 0.5])
    for key, fn in fns.items():
        info = summary["functions"][key]
        assert info["n_nodes"] == fn.n_nodes() and info["n_instructions"] == fn.n_instructions()
        loaded = ca.Function.load(str(out / info["file"]))
        ext = ca.external(fn.name(), str(out / "softpinn_eom.so"))
        args = [q] + ([q[::-1]] if fn.n_in() > 1 else [])
        np.testing.assert_allclose(np.asarray(loaded(*args)), np.asarray(fn(*args)), rtol=1e-14)
        np.testing.assert_allclose(np.asarray(ext(*args)), np.asarray(fn(*args)), rtol=1e-12)


def test_task4_generated_code_agrees_with_mx(tmp_path):
    """The real equations of motion (engineer A's functions) through the C compiler."""
    from softpinn.symbolic.model._functions import functions

    fns = functions("task4")
    res = codegen.compile_functions(fns, directory=tmp_path)
    rng = np.random.default_rng(4)
    for key, fn in fns.items():
        for _ in range(3):
            args = [rng.uniform(-1, 1, size=fn.size_in(i)) for i in range(fn.n_in())]
            ref = fn.call(args)
            got = res.functions[key].call(args)
            for a, b in zip(got, ref, strict=True):
                np.testing.assert_allclose(
                    np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12, err_msg=key
                )
