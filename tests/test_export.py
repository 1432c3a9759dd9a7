"""Export of trained runs to CasADi and C (bridge/export): the exported Functions, read back from
disk and from the compiled library, agree with the JAX model in float64 at random states for
every model kind (q̈, the step, M, M⁻¹, G, D, A), their Jacobians agree with JAX's, ensembles
export one member or the mean, and bad inputs give one-line errors."""

from __future__ import annotations

import json

import casadi as ca
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, tiny_model_config

from softpinn.bridge import cli
from softpinn.bridge.export import export_run, load_exported
from softpinn.errors import UserError
from softpinn.learn import TrainConfig, load_run, step, train

#: the kinds, and the training options that shape ``step`` (sub-steps, input hold)
KINDS = {
    "lagrangian": dict(substeps=2, input_hold="linear"),
    "lagrangian-hessian": dict(substeps=1, input_hold="constant"),
    "hamiltonian": dict(substeps=3, input_hold="constant"),
    "blackbox": dict(substeps=1, input_hold="linear"),
}
MODEL_KW = {"lagrangian": dict(activation="tanh", damping_form="constant")}


#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("msd") / "msd.npz", trajectories=3, duration=2.0)


@pytest.fixture(scope="module")
def runs(data, tmp_path_factory):
    """``get(kind, seeds=1)``: a tiny run trained for 3 epochs, once per module."""
    root = tmp_path_factory.mktemp("runs")
    cache = {}

    def get(kind, seeds=1):
        if (kind, seeds) not in cache:
            cfg = TrainConfig(
                model=tiny_model_config(kind, **MODEL_KW.get(kind, {})),
                epochs=3, batch_size=64, lr=1e-2, test_trajectories=(2,), seeds=seeds,
                checkpoint_every=1000, **KINDS[kind],
            )
            out = root / f"{kind}-{seeds}"
            train(data, cfg, out)
            cache[kind, seeds] = out
        return cache[kind, seeds]

    return get


def _states(n, m, count=6, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield (rng.uniform(-1.5, 1.5, n), rng.uniform(-2, 2, n), rng.uniform(-1, 1, m),
               rng.uniform(-1, 1, m), rng.uniform(0.01, 0.1))


def _jax_qdd(model):
    n = model.config.n
    if model.config.kind == "blackbox":
        return lambda q, qd, u: model.vector_field(jnp.concatenate([q, qd]), u)[n:]
    return model.qdd


def _close(got, want, tol, what):
    got = np.asarray(got, float).reshape(np.shape(want))
    np.testing.assert_allclose(got, np.asarray(want), rtol=tol, atol=tol, err_msg=what)


def _reference(models, train_cfg):
    """JAX values at random states (the mean over ``models``; one model: itself)."""
    first = models[0]
    n, m = first.config.n, first.config.m
    kw = dict(substeps=train_cfg.substeps, input_hold=train_cfg.input_hold)
    physics = first.config.kind != "blackbox"

    @jax.jit
    def values(q, qd, u, u1, dt):
        x = jnp.concatenate([q, qd])
        out = {"qdd": [], "field": []} | ({k: [] for k in ("M", "M_inv", "G", "D", "A")}
                                           if physics else {})
        for mod in models:
            out["qdd"].append(_jax_qdd(mod)(q, qd, u))
            out["field"].append(mod.vector_field(x, u))
            for name, value in (mod.matrices(q) if physics else {}).items():
                out[name].append(value)
        out = {k: jnp.mean(jnp.stack(v), axis=0) for k, v in out.items()}
        if len(models) == 1:
            out["step"] = step(first, x, u, u1, dt, **kw)
        return out

    return [(args, values(*args)) for args in _states(n, m)]


def _check_against_jax(fns, reference, tol=1e-10):
    """Every exported Function against the JAX values of :func:`_reference`."""
    for (q, qd, u, u1, dt), want in reference:
        x = np.concatenate([q, qd])
        _close(fns["qdd"](q, qd, u), want["qdd"], tol, "qdd")
        _close(fns["field"](x, u), want["field"], tol, "field")
        if "step" in want:
            _close(fns["step"](x, u, u1, dt), want["step"], tol, "step")
        for name in ("M", "M_inv", "G", "D", "A"):
            if name in want:
                _close(fns[name](q), want[name], tol, name)


@pytest.mark.parametrize("kind", list(KINDS))
def test_export_agrees_with_jax(kind, runs, tmp_path):
    run = load_run(runs(kind))
    meta = export_run(runs(kind), tmp_path / "x")
    out = tmp_path / "x"
    for name in ("model.casadi", "model.c", "model.h", "model.json", "step.casadi"):
        assert (out / name).is_file(), name
    model = ca.Function.load(str(out / "model.casadi"))
    assert model.name() == "qdd" and list(model.name_in()) == ["q", "qd", "u"]
    step_fn = ca.Function.load(str(out / "step.casadi"))
    assert list(step_fn.name_in()) == ["x", "u0", "u1", "dt"]
    assert meta["step"] == {"method": "rk4", **KINDS[kind]}
    reference = _reference([run.model], run.train_config)
    _check_against_jax(load_exported(out), reference)
    # the C library built through the code cache computes the same
    assert (out / "model.so").is_file() and meta["c"]["library"] == "model.so"
    so = str((out / "model.so").absolute())
    compiled = {k: ca.external(f.name(), so) for k, f in load_exported(out).items()}
    _check_against_jax(compiled, reference)
    header = (out / "model.h").read_text()
    assert "int qdd(" in header and "int step(" in header
    saved = json.loads((out / "model.json").read_text())
    assert saved["kind"] == kind and saved["n"] == 2 and saved["m"] == 1
    assert saved["coordinates"] == ["q1", "q2"] and len(saved["run"]["sha256"]) == 64
    assert saved["training"]["dataset"]["sha256"] == run.info["dataset"]["sha256"]
    assert saved["state_kind"] == run.model.state_kind
    # the configurations the model was fitted on: the training trajectories' q range
    with np.load(run.info["dataset"]["path"]) as z:
        q = z["q"][np.isin(z["traj"], run.info["split"]["train"])]
    rng = saved["training"]["q_range"]
    assert rng["trajectories"] == run.info["split"]["train"]
    np.testing.assert_array_equal(rng["min"], q.min(axis=0))
    np.testing.assert_array_equal(rng["max"], q.max(axis=0))


@pytest.mark.parametrize("kind", ["lagrangian", "hamiltonian", "blackbox"])
def test_jacobians_agree_with_jax(kind, runs, tmp_path):
    run = load_run(runs(kind))
    fns = export_run(runs(kind), tmp_path / "x").functions
    model, cfg = run.model, run.train_config
    jq = fns["qdd"].jacobian()
    js = fns["step"].jacobian()
    kw = dict(substeps=cfg.substeps, input_hold=cfg.input_hold)
    d_qdd = jax.jit(jax.jacfwd(_jax_qdd(model), argnums=(0, 1, 2)))
    d_step = jax.jit(jax.jacfwd(lambda x, a, b, dt: step(model, x, a, b, dt, **kw),
                                argnums=(0, 1, 2)))
    for q, qd, u, u1, dt in _states(2, 1, count=4, seed=1):
        got = jq(q, qd, u, 0)
        for g, w, name in zip(got, d_qdd(q, qd, u), ("q", "qd", "u"), strict=True):
            _close(g, w, 1e-8, f"dqdd/d{name}")
        x = np.concatenate([q, qd])
        want = d_step(x, u, u1, dt)
        got = js(x, u, u1, dt, 0)
        for g, w, name in zip(got[:3], want, ("x", "u0", "u1"), strict=True):
            _close(g, w, 1e-8, f"dstep/d{name}")


_C_MAIN = r"""
#include <stdio.h>
#include "model.h"
int main(void) {
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    qdd_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    const casadi_real q[2] = {0.3, -0.2}, qd[2] = {0.5, 0.1}, u[1] = {0.4};
    casadi_real out[2], w[4096];
    casadi_int iw[256];
    const casadi_real* arg[16] = {q, qd, u};
    casadi_real* res[16] = {out};
    if (sz_w > 4096 || sz_iw > 256 || sz_arg > 16 || sz_res > 16) return 3;
    if (qdd(arg, res, iw, w, 0)) return 4;
    printf("%.17g %.17g\n", out[0], out[1]);
    return 0;
}
"""


def test_c_user_includes_the_header(runs, tmp_path):
    """A C program includes model.h, links model.so and gets JAX's q̈."""
    import shutil
    import subprocess

    cc = shutil.which("gcc") or shutil.which("cc")
    assert cc, "the test machine has a C compiler"
    out = tmp_path / "x"
    export_run(runs("lagrangian"), out)
    (tmp_path / "main.c").write_text(_C_MAIN)
    exe = tmp_path / "main"
    subprocess.run([cc, str(tmp_path / "main.c"), f"-I{out}", str(out / "model.so"), "-o",
                    str(exe), f"-Wl,-rpath,{out}", "-lm"], check=True)
    got = np.array(subprocess.run([str(exe)], capture_output=True, text=True,
                                  check=True).stdout.split(), float)
    want = load_run(runs("lagrangian")).model.qdd(np.array([0.3, -0.2]), np.array([0.5, 0.1]),
                                                  np.array([0.4]))
    _close(got, want, 1e-12, "qdd from C")


def test_ensemble_member_and_mean(runs, tmp_path):
    run_dir = runs("lagrangian", seeds=2)
    members = [load_run(run_dir, member=s) for s in (0, 1)]
    one = export_run(run_dir, tmp_path / "one", member=1)
    assert one["ensemble"]["seeds"] == [1] and one["ensemble"]["mode"] == "member"
    _check_against_jax(load_exported(tmp_path / "one"),
                       _reference([members[1].model], members[1].train_config))
    mean = export_run(run_dir, tmp_path / "mean", mean=True)
    assert mean["ensemble"]["seeds"] == [0, 1] and mean["ensemble"]["mode"] == "mean"
    fns = load_exported(tmp_path / "mean")
    _check_against_jax(fns, _reference([m.model for m in members], members[0].train_config))
    # the mean model is not either member
    q, qd, u = np.array([0.3, -0.2]), np.array([0.5, 0.1]), np.array([0.4])
    assert not np.allclose(np.asarray(fns["qdd"](q, qd, u)).ravel(),
                           np.asarray(members[0].model.qdd(q, qd, u)))


def _cli(monkeypatch, capsys, *argv):
    """``softpinn export ...`` through the real ``main``."""
    status = cli.main(["export", *map(str, argv)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_cli_export_and_bad_inputs(runs, tmp_path, monkeypatch, capsys):
    run = runs("lagrangian", seeds=2)
    status, out, err = _cli(monkeypatch, capsys, run, "--out", tmp_path / "ok", "--member", 0)
    assert status == 0 and "exported lagrangian model" in out
    # the stages on stderr as they start (the compile can take a minute), and nothing else
    stages = err.strip().splitlines()
    assert stages and all(line.startswith("export: ") for line in stages), err
    assert any("compiling" in line for line in stages)
    assert (tmp_path / "ok" / "model.so").is_file()

    def error(*argv):
        status, _, err = _cli(monkeypatch, capsys, *argv)
        assert status == 2 and err.startswith("softpinn: error: ") and err.count("\n") == 1, err
        assert "Traceback" not in err
        return err

    (tmp_path / "empty").mkdir()
    assert "not a softpinn run directory (no config.json)" in error(tmp_path / "empty", "--out",
                                                                     tmp_path / "a")
    assert "no such directory" in error(tmp_path / "nope", "--out", tmp_path / "a")
    err = error(run, "--out", tmp_path / "b", "--member", 7)
    assert "--member 7" in err and "seeds [0, 1]" in err
    err = error(runs("hamiltonian"), "--out", tmp_path / "b", "--member", 5)
    assert "--member 5" in err and "single-model run" in err
    (tmp_path / "file").write_text("x")
    assert "cannot write there" in error(run, "--out", tmp_path / "file" / "sub")
    assert "not a directory" in error(run, "--out", tmp_path / "file")
    err = error(run, "--out", tmp_path / "ok")
    assert "--force" in err and "not empty" in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    status, _, _ = _cli(monkeypatch, capsys, run, "--out", tmp_path / "ok", "--mean", "--force")
    assert status == 0
    assert json.loads((tmp_path / "ok" / "model.json").read_text())["ensemble"]["mode"] == "mean"
    # --mean of a single-model run is that model, and says so
    one = runs("hamiltonian")
    status, out, err = _cli(monkeypatch, capsys, one, "--out", tmp_path / "one", "--mean")
    assert status == 0 and "holds one model: --mean exports that one" in err and ", mean" not in out
    assert json.loads((tmp_path / "one" / "model.json").read_text())["ensemble"]["mode"] == "member"


def test_library_errors_are_user_errors(runs, tmp_path):
    with pytest.raises(UserError, match="exclude each other"):
        export_run(runs("lagrangian", seeds=2), tmp_path / "x", member=0, mean=True)
    with pytest.raises(UserError, match="no model.json"):
        load_exported(tmp_path)
