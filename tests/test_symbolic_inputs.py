"""Bad input to the symbolic side is one line, never a traceback, NaN or a runaway (issue 15):
every numeric option of derive / simulate / matrices is checked where it enters (NaN and
infinities included), a spec that is not UTF-8 or too big to derive is refused naming the file,
``matrices`` at a singular state refuses instead of printing NaN, JSON output is strict, an
unwritable compiled-code cache falls back to CasADi's virtual machine with one warning, and the
library raises :class:`UserError` (not a numpy or CasADi error) for wrong shapes or values."""

from __future__ import annotations

import json
import warnings

import casadi as ca
import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.symbolic import TrueModel, UserError
from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen import _codegen as codegen
from softpinn.symbolic.model._functions import functions
from softpinn.symbolic.simulation._datasets import plan_dataset
from softpinn.symbolic.spec._spec import MAX_COORDINATES, SpecError, load_spec


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path_factory.getbasetemp() / "inputs-cache"))


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


PHI_THETA = (
    'name = "pt"\nkind = "spatial-pcc"\nparameterization = "phi-theta"\nactuation = "none"\n'
    "[[segment]]\nlength = 0.2\nmass = 0.3\nstiffness = [0.0, 1.0, 1.0]\n"
)
SIM = ["simulate", "task1", "--out", "{tmp}/a.npz", "--quiet"]


@pytest.mark.parametrize(
    "argv,message",
    [
        (SIM + ["--seed", "-1"], "--seed: expected an integer from 0 to 4294967295"),
        (SIM + ["--seed", str(2**32)], "--seed: expected an integer from 0 to 4294967295"),
        (["derive", "task1", "--out", "{tmp}/d", "--timeout", "nan"],
         "--timeout: must be a finite number > 0, got nan"),
        (["derive", "task1", "--out", "{tmp}/d", "--timeout", "inf"],
         "--timeout: must be a finite number > 0, got inf"),
        (["derive", "task1", "--out", "{tmp}/d", "--timeout", "-3"],
         "--timeout: must be positive, got -3.0"),
        (SIM + ["--duration", "nan"], "--duration: must be a finite number > 0, got nan"),
        (SIM + ["--duration", "inf"], "--duration: must be a finite number > 0, got inf"),
        (SIM + ["--rate", "nan"], "--rate: must be a finite number > 0, got nan"),
        (SIM + ["--dt", "nan"], "--dt: must be a finite number > 0, got nan"),
        (SIM + ["--rtol", "nan"], "--rtol: must be a finite number > 0, got nan"),
        (SIM + ["--atol=-inf"], "--atol: must be positive, got -inf"),
        (SIM + ["--noise", "nan"], "--noise: must be a non-negative standard deviation"),
        (SIM + ["--settle", "inf"], "--settle: must be a non-negative number of seconds"),
        (SIM + ["--threads", "0"], "--threads: must be at least 1"),
        (SIM + ["--trajectories", "-2"], "--trajectories: must be at least 1"),
        (SIM + ["--duration", "1e300", "--rate", "1e300"],
         "samples per trajectory"),
        (SIM + ["--duration", "1e7"], "more than this machine's"),
        (SIM + ["--trajectories", "100000000000"], "more than this machine's"),
        (SIM + ["--dt", "1e-12", "--rate", "10", "--duration", "1"],
         "--dt: 1e-12 s makes 1e+11 RK4 steps per output interval"),
        (["matrices", "task2", "--q", "nan", "0"], "--q: values must be finite"),
        (["matrices", "{tmp}/latin1.toml", "--q", "0"],
         "latin1.toml: not a UTF-8 text file (byte 0xe9 on line 1)"),
        (["derive", "{tmp}/long.toml", "--out", "{tmp}/d"],
         "long.toml: field 'segment': 40 segments give 120 coordinates, more than the 24"),
        (["derive", "{tmp}/chain.toml", "--out", "{tmp}/d"],
         "chain.toml: field 'masses': 30 masses give 30 coordinates"),
        (["matrices", "{tmp}", "--q", "0"], "is a folder, not a spec file"),
        (["matrices", "{tmp}/pt.toml", "--q", "0", "0", "0"],
         "model 'pt' at q = [0, 0, 0]: M_inv is not finite; the model is singular there"),
        (["matrices", "{tmp}/pt.toml", "--q", "0", "0", "0", "--json"],
         'use parameterization = "delta"'),
        (["derive", "task1", "--out", "{tmp}/d", "--compiler", "/nonexistent/cc"],
         "--compiler /nonexistent/cc: no such compiler"),
        (["derive", "task1", "--out", "{tmp}/afile/d"], "--out {tmp}/afile/d: cannot write"),
        (["simulate", "task1", "--out", "{tmp}/afile/a.npz"], "--out {tmp}/afile/a.npz: cannot"),
        (["simulate", "task1", "--out", "{tmp}/dir.npz"], "is a folder, not a dataset file"),
    ],
)
def test_one_line_errors(capsys, tmp_path, argv, message):
    (tmp_path / "latin1.toml").write_bytes('name = "bras articulé"\n'.encode("latin-1"))
    seg = "[[segment]]\nlength = 0.2\nmass = 0.3\nstiffness = [1.0, 1.0, 1.0]\n"
    (tmp_path / "long.toml").write_text('kind = "spatial-pcc"\n' + seg * 40)
    (tmp_path / "chain.toml").write_text(
        f'kind = "mass-spring-damper"\nmasses = {[1.0] * 30}\nsprings = {[1.0] * 30}\n'
    )
    (tmp_path / "pt.toml").write_text(PHI_THETA)
    (tmp_path / "afile").write_text("a file, not a folder")
    (tmp_path / "dir.npz").mkdir()
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    status, out, err = run(capsys, *argv)
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("softpinn: error: ")
    assert message.replace("{tmp}", str(tmp_path)) in lines[0]
    assert out == "" and not (tmp_path / "a.npz").exists() and not (tmp_path / "d").exists()


def test_matrices_json_is_strict_away_from_the_singularity(capsys, tmp_path):
    (tmp_path / "pt.toml").write_text(PHI_THETA)
    status, out, _ = run(capsys, "matrices", tmp_path / "pt.toml", "--q", 0.3, 0.2, 0.0, "--json")
    assert status == 0
    d = json.loads(out, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert np.all(np.isfinite(d["M_inv"]))


def test_strict_json_names_the_non_finite_value():
    assert outputs.dumps({"a": [1.0, 2]}) == '{"a": [1.0, 2]}'
    with pytest.raises(UserError, match=r"matrices: M_inv\[1\]\[0\] is not a finite number"):
        outputs.dumps({"M_inv": [[1.0, 0.0], [float("nan"), 1.0]]}, what="matrices")
    with pytest.raises(UserError, match=r"x: timings_s\.derive is not a finite number"):
        outputs.dumps({"timings_s": {"derive": float("inf")}}, what="x")


def test_an_unwritable_cache_falls_back_to_the_virtual_machine(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    fns = {"M": ca.Function("unwritable_M", [ca.SX.sym("q")], [ca.SX.sym("q") * 0 + 2.0])}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = codegen.compile_functions(fns, directory=blocker / "cache")
    assert not res.compiled and res.functions["M"] is fns["M"]
    msgs = [str(w.message) for w in caught if issubclass(w.category, codegen.CompilerWarning)]
    assert len(msgs) == 1 and "cannot be written" in msgs[0] and "virtual machine" in msgs[0]
    with pytest.raises(codegen.CompilerError, match="cannot be written"):
        codegen.compile_functions(fns, directory=blocker / "cache", fallback=False)
    # the CLI: one warning line, and the command succeeds
    monkeypatch.setenv("SOFTPINN_CACHE", str(blocker / "cli-cache"))
    status, _, err = run(capsys, "simulate", "task1", "--out", tmp_path / "a.npz", "--quiet",
                         "--trajectories", 2, "--duration", 0.2)
    assert status == 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("softpinn: warning: the compiled-code cache")
    monkeypatch.setenv("SOFTPINN_CACHE", str(blocker / "derive-cache"))
    status, _, err = run(capsys, "derive", "task1", "--out", tmp_path / "d")
    assert status == 0 and (tmp_path / "d" / "softpinn_eom.so").is_file()
    assert err.count("\n") == 1 and "was not installed there" in err


@pytest.fixture(scope="module")
def tm():
    return TrueModel("task4")


@pytest.mark.parametrize(
    "call,message",
    [
        (lambda tm: tm.M(np.zeros(2)), "q: expected length 3 for model 'task4', got 2"),
        (lambda tm: tm.M(np.array([0.1, np.nan, 0.0])), "q: values must be finite, got nan at"),
        (lambda tm: tm.qdd(np.zeros(3), np.zeros((2, 2))), "qd: expected length 3"),
        (lambda tm: tm.qdd(np.zeros(3), np.zeros(3), [0, np.inf, 0]),
         "u: values must be finite, got inf at index 1"),
        (lambda tm: tm.C(np.zeros((4, 3)), np.full((4, 3), np.nan)), r"qd: values must be finite"),
        (lambda tm: tm.C(np.zeros(3), "abc"), "qd: expected real numbers, got 'abc'"),
        (lambda tm: tm.M([1j, 0, 0]), "q: expected real numbers"),
        (lambda tm: tm.ode(1.0), r"x: expected shape \(6,\) or \(N, 6\), got \(\)"),
        (lambda tm: tm.call("nope", q=np.zeros(3)), "nope: not a function of the model"),
        (lambda tm: TrueModel("task4", order=0), "order: expected an integer from 1 to 100"),
        (lambda tm: TrueModel("task4", order=2.5), "order: expected an integer from 1 to 100"),
        (lambda tm: TrueModel("task4", order=True), "order: expected an integer"),
        (lambda tm: functions("task4", order=-1), "order: expected an integer"),
        (lambda tm: TrueModel("task4", compiled="yes"), "compiled: expected None, True or False"),
    ],
)
def test_library_errors_are_user_errors(tm, call, message):
    with pytest.raises(UserError, match=message):
        call(tm)


def test_an_empty_batch_gives_empty_results(tm):
    assert tm.M(np.zeros((0, 3))).shape == (0, 3, 3)
    assert tm.energy(np.zeros((0, 3)), np.zeros(3)).shape == (0,)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"seed": -1}, "seed: expected an integer from 0 to 4294967295"),
        ({"seed": 2**32}, "seed: expected an integer from 0 to 4294967295"),
        ({"seed": 1.5}, "seed: expected an integer"),
        ({"trajectories": 2.5}, "trajectories: must be an integer of at least 1"),
    ],
)
def test_dataset_plan_checks_seeds_and_counts(kwargs, message):
    with pytest.raises(UserError, match=message):
        plan_dataset("task1", **kwargs)


def test_spec_files_that_cannot_be_read(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * 200_000)
    with pytest.raises(SpecError, match="too large for a spec file"):
        load_spec(big)
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'kind = "double-pendulum"\n# \xff\xfe\n')
    with pytest.raises(SpecError, match=r"bad.toml: not a UTF-8 text file \(byte 0xff on line 2\)"):
        load_spec(bad)
    seed = tmp_path / "seed.toml"
    seed.write_text(
        'kind = "mass-spring-damper"\nmasses = [1.0]\nsprings = [1.0]\n[data]\nseed = 4294967296\n'
    )
    with pytest.raises(UserError, match="field 'data.seed': expected an integer from 0 to"):
        plan_dataset(seed)


def test_the_coordinate_limit_lets_the_largest_supported_specs_load():
    seg = "[[segment]]\nlength = 0.2\nmass = 0.3\nstiffness = [1.0, 1.0, 1.0]\n"
    from softpinn.symbolic.spec._spec import spec_from_toml

    spec = spec_from_toml('kind = "spatial-pcc"\n' + seg * (MAX_COORDINATES // 3), source="x")
    assert spec.n == MAX_COORDINATES
    with pytest.raises(SpecError, match="at most 8 here"):
        spec_from_toml('kind = "spatial-pcc"\n' + seg * (MAX_COORDINATES // 3 + 1), source="x")
