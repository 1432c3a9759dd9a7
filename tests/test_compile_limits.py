"""The C compiler's limit (issue 46): ``--compile-timeout`` of ``export`` and ``control`` is
checked in one line and reaches the compiler; a compile past it names the flag (not
quadrature nodes, which a network has none of) and leaves the export folder as it was;
``export --no-compile`` and ``control --no-codegen`` build no library, and the export still
loads and runs in CasADi's virtual machine."""

from __future__ import annotations

import json

import numpy as np
import pytest
from clihelp import one_line_error, run_cli
from datagen import make_dataset, tiny_model_config

from softpinn.bridge import cli
from softpinn.bridge.control import MPC, MPCConfig, from_run, from_true, tip_output
from softpinn.bridge.export import export_run, load_exported
from softpinn.errors import UserError
from softpinn.symbolic import CompilerTimeout, TrueModel, find_compiler, load_spec
from softpinn.symbolic.codegen import _codegen


@pytest.fixture
def cc():
    """A test that compiles: the test machine has a C compiler (as tests/test_export.py
    asserts), so its absence fails the test instead of skipping it."""
    assert find_compiler() is not None, "the test machine has a C compiler"


needs_cc = pytest.mark.usefixtures("cc")


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """A cache of each test's own: nothing is served from an earlier compile."""
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny Lagrangian run on the forced chain's data (3 epochs)."""
    from softpinn.learn import TrainConfig, train

    data = make_dataset(tmp_path_factory.mktemp("msd") / "msd.npz", trajectories=3,
                        duration=2.0)
    out = tmp_path_factory.mktemp("runs") / "lagrangian"
    train(data, TrainConfig(model=tiny_model_config("lagrangian"), epochs=3, batch_size=64,
                            lr=1e-2, test_trajectories=(2,), checkpoint_every=1000), out)
    return out


# ------------------------------------------------------------------ the flag's checks


@pytest.mark.parametrize("value", ["0", "-5", "nan", "inf", "soon"])
def test_export_flag_is_checked_in_one_line(capsys, tmp_path, value):
    err = one_line_error(capsys, "export", tmp_path / "no-run", "--out", tmp_path / "e",
                          "--compile-timeout", value)
    assert "--compile-timeout" in err
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_control_flag_is_checked_in_one_line(capsys, tmp_path, msd_spec, value):
    err = one_line_error(capsys, "control", msd_spec, "--out", tmp_path / "c",
                          "--compile-timeout", value)
    assert "--compile-timeout" in err
    assert not (tmp_path / "c").exists()


def test_library_checks_the_limit(tmp_path):
    with pytest.raises(UserError, match="--compile-timeout"):
        export_run(tmp_path / "no-run", tmp_path / "e", compile_timeout=0)
    with pytest.raises(UserError, match="compile_timeout"):
        MPCConfig(compile_timeout=-1.0)
    assert MPCConfig(compile_timeout=1200).compile_timeout == 1200


def test_help_says_what_no_codegen_skips(capsys):
    with pytest.raises(SystemExit):
        cli.main(["control", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--compile-timeout S" in text and "model.so" in text
    with pytest.raises(SystemExit):
        cli.main(["export", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--no-compile" in text and "--compile-timeout S" in text


# ------------------------------------------------------------------ the limit reaches gcc


@needs_cc
def test_export_limit_reaches_the_compiler(run, tmp_path, monkeypatch):
    seen = []
    real = _codegen.compile_c

    def recording(*args, **kwargs):
        seen.append(kwargs["timeout"])
        return real(*args, **kwargs)

    monkeypatch.setattr(_codegen, "compile_c", recording)
    meta = export_run(run, tmp_path / "e", compile_timeout=123.5)
    assert seen == [123.5] and meta["c"]["library"] == "model.so"


@needs_cc
def test_export_past_the_limit_names_the_flag_and_writes_nothing(run, tmp_path, capsys):
    out = tmp_path / "e"
    err = one_line_error(capsys, "export", run, "--out", out, "--compile-timeout", "0.001",
                          "--json")  # --json: no progress lines on stderr
    assert "ran past its timeout of 0.001 s on the export's" in err
    assert "--compile-timeout" in err and "--no-compile" in err
    assert "quadrature" not in err
    assert not out.exists()
    # an earlier export in --out (with --force) is left as it was, not half replaced
    export_run(run, out, compile=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    one_line_error(capsys, "export", run, "--out", out, "--force", "--compile-timeout",
                    "0.001", "--json")
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    load_exported(out)  # its checksums still hold


@needs_cc
def test_control_solver_past_the_limit_names_the_flags(msd_spec, tmp_path):
    spec = load_spec(msd_spec)
    tm = TrueModel(spec)
    model = from_true(tm, tip_output(spec))
    with pytest.raises(CompilerTimeout) as info:
        MPC(model, MPCConfig(horizon=3, compile_timeout=0.001), cache=tmp_path / "cc")
    text = str(info.value)
    assert "--compile-timeout" in text and "--no-codegen" in text
    assert "\n" not in text


@needs_cc
def test_a_true_models_timeout_keeps_the_quadrature_advice(tmp_path):
    import casadi as ca

    x = ca.SX.sym("x")
    fns = {"f": ca.Function("limit_toy", [x], [ca.sin(x) * x])}
    with pytest.raises(CompilerTimeout, match="fewer quadrature nodes"):
        _codegen.compile_functions(fns, directory=tmp_path, timeout=0.001)


# ------------------------------------------------------------------ no library


def test_export_without_a_library_loads_and_runs(run, tmp_path, capsys):
    out = tmp_path / "e"
    status, text, _ = run_cli(capsys, "export", run, "--out", out, "--no-compile")
    assert status == 0 and "no library (--no-compile)" in text, text
    assert (out / "model.c").is_file() and (out / "model.h").is_file()
    assert not (out / "model.so").exists()
    meta = json.loads((out / "model.json").read_text())
    assert meta["c"]["library"] is None and "--no-compile" in meta["c"]["note"]
    fns = load_exported(out)
    q, qd, u = np.array([0.1, -0.2]), np.array([0.3, 0.0]), np.array([0.5])
    a = np.asarray(fns["qdd"](q, qd, u)).ravel()
    assert a.shape == (2,) and np.all(np.isfinite(a))
    if find_compiler() is not None:  # the same numbers as a compiled export's library
        import casadi as ca

        export_run(run, tmp_path / "c")
        lib = ca.external(fns["qdd"].name(), str(tmp_path / "c" / "model.so"))
        np.testing.assert_allclose(np.asarray(lib(q, qd, u)).ravel(), a, rtol=1e-12,
                                   atol=1e-12)


def test_control_no_codegen_exports_no_library(run, msd_spec, tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(_codegen, "compile_c", lambda *a, **k: calls.append(k) or 0.0)
    spec = load_spec(msd_spec)
    pm = from_run(run, tip_output(spec), export_dir=tmp_path / "x", compile=False)
    assert not (tmp_path / "x" / "model.so").exists() and calls == []
    x = np.asarray(pm.field(np.zeros(pm.nx), np.zeros(pm.m))).ravel()
    assert np.all(np.isfinite(x))


def test_cli_control_no_codegen_compiles_nothing(run, msd_spec, tmp_path, capsys,
                                                 monkeypatch):
    calls = []
    monkeypatch.setattr(_codegen, "compile_c", lambda *a, **k: calls.append(k) or 0.0)
    out = tmp_path / "c"
    status, text, err = run_cli(capsys, "control", msd_spec, "--runs", run, "--out", out,
                             "--no-true", "--no-linear", "--no-codegen", "--reference", "step",
                             "--duration", "0.2", "--horizon", "5", "--rate", "20", "--quiet")
    assert status == 0, err
    assert calls == []
    exported = out / "models" / "lagrangian"
    assert (exported / "model.json").is_file() and not (exported / "model.so").exists()


@needs_cc
def test_a_large_source_compiles_at_O0(run, tmp_path, monkeypatch):
    """Above LARGE_SOURCE_MB the export's C compiles at -O0 (minutes saved on a large
    network); model.json says which flags built the library."""
    from softpinn.bridge.export import writer

    monkeypatch.setattr(writer, "LARGE_SOURCE_MB", 0.0)
    logged = []
    meta = export_run(run, tmp_path / "e", log=logged.append)
    assert meta["c"]["flags"][0] == "-O0" and meta["c"]["library"] == "model.so"
    assert any("at -O0" in line for line in logged)
    monkeypatch.setattr(writer, "LARGE_SOURCE_MB", 1e9)
    assert export_run(run, tmp_path / "f")["c"]["flags"][0] == "-O1"
