"""Issue 44, classes 2-4: exports carry the sha256 of every file they write and every loader
(`load_exported`, `from_export`, `softpinn control --runs`) refuses a changed or missing file in
one line before CasADi reads it (an export from before the checksums still loads); a refused
command leaves nothing (`control`'s bounds and duration, `analyze --q nan`, a refusal after the
claim); values that describe no arm or no network address are refused where they enter
(`control --center`/`--radius`, `train --coordinator`, `import --out` a folder)."""

from __future__ import annotations

import hashlib
import importlib
import json
import shutil

import pytest
from clihelp import one_line_error, run_cli
from datagen import make_dataset, tiny_model_config

from softpinn.bridge.control import ControlConfig, MPCConfig, compare, from_export, tip_output
from softpinn.bridge.export import export_run, load_exported
from softpinn.errors import UserError
from softpinn.symbolic import load_spec

#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("msd") / "msd.npz", trajectories=3,
                        duration=2.0)


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    """A tiny Lagrangian run on the forced chain's data."""
    from softpinn.learn import TrainConfig, train

    cfg = TrainConfig(model=tiny_model_config("lagrangian"), epochs=2, batch_size=64, lr=1e-2,
                      test_trajectories=(2,), checkpoint_every=1000)
    out = tmp_path_factory.mktemp("runs") / "lnn"
    train(data, cfg, out)
    return out


@pytest.fixture(scope="module")
def exported(run, tmp_path_factory):
    out = tmp_path_factory.mktemp("exports") / "lnn"
    export_run(run, out)
    return out


def _copy(exported, tmp_path, name="copy"):
    target = tmp_path / name
    shutil.copytree(exported, target)
    return target


def _flip(path, offset=None):
    raw = bytearray(path.read_bytes())
    i = len(raw) // 2 if offset is None else offset
    raw[i] ^= 0x01
    path.write_bytes(bytes(raw))



#: the cheapest comparison: two control steps with the learned model alone, no C
QUICK = ("--reference", "step", "--duration", "0.1", "--rate", "20", "--horizon", "3",
         "--no-true", "--no-linear", "--no-codegen")


# --- 2. verified exports ------------------------------------------------------------------
def test_an_export_lists_the_sha256_of_every_file_it_wrote(exported, msd_spec):
    meta = json.loads((exported / "model.json").read_text())
    sums = meta["sha256"]
    written = {p.name for p in exported.iterdir() if p.is_file() and p.name != "model.json"}
    assert set(sums) == written
    assert {"model.casadi", "field.casadi", "step.casadi", "model.c", "model.h"} <= written
    if meta["c"]["library"]:
        assert meta["c"]["library"] in sums
    for name, sha in sums.items():
        assert hashlib.sha256((exported / name).read_bytes()).hexdigest() == sha
    assert set(load_exported(exported)) == set(meta["functions"])
    model = from_export(exported, tip_output(load_spec(msd_spec)))
    assert model.info["verified"] is True


def test_a_flipped_byte_is_refused_by_every_loader(exported, msd_spec, tmp_path, capsys):
    meta = json.loads((exported / "model.json").read_text())
    targets = ["field.casadi", "model.c"] + ([meta["c"]["library"]] if meta["c"]["library"]
                                             else [])
    output = tip_output(load_spec(msd_spec))
    for name in targets:
        bad = _copy(exported, tmp_path, f"bad-{name}")
        _flip(bad / name)
        for load, args in ((load_exported, (bad,)), (from_export, (bad, output))):
            with pytest.raises(UserError) as info:
                load(*args)
            text = str(info.value)
            assert str(bad / name) in text and "changed since softpinn export" in text
            assert "\n" not in text
        out = tmp_path / f"out-{name}"
        err = one_line_error(capsys, "control", msd_spec, "--runs", bad, "--out", out, *QUICK)
        assert str(bad / name) in err and not out.exists()


def test_a_missing_file_is_refused_in_one_line(exported, tmp_path):
    bad = _copy(exported, tmp_path)
    (bad / "field.casadi").unlink()
    with pytest.raises(UserError, match=r"field\.casadi: missing \(model\.json lists it\)"):
        load_exported(bad)
    (bad / "model.json").write_text("{not json")
    with pytest.raises(UserError, match="model.json: cannot be read"):
        load_exported(bad)


def test_an_export_from_before_the_checksums_still_loads(exported, msd_spec, tmp_path, capsys):
    old = _copy(exported, tmp_path)
    meta = json.loads((old / "model.json").read_text())
    del meta["sha256"]
    (old / "model.json").write_text(json.dumps(meta))
    assert set(load_exported(old)) == set(meta["functions"])
    assert from_export(old, tip_output(load_spec(msd_spec))).info["verified"] is False
    status, _, err = run_cli(capsys, "control", msd_spec, "--runs", old, "--out", tmp_path / "ok",
                          *QUICK)
    assert status == 0, err
    assert "not verified" in err


# --- 3. checked before claimed -------------------------------------------------------------

@pytest.mark.parametrize("argv, said", [
    (("--u-min", "1", "--u-max", "0"), "--u-min 1 exceeds --u-max 0"),
    (("--u-min", "100"), "exceeds the default upper bound"),
    (("--duration", "0.001"), "--duration: 0.001 s is shorter than one control step"),
    (("--rate", "1e9"), "--rate: 1e+09 Hz over"),
])
def test_control_refuses_before_it_claims_out(msd_spec, tmp_path, capsys, argv, said):
    out = tmp_path / "out"
    assert said in one_line_error(capsys, "control", msd_spec, "--out", out, *argv)
    assert not out.exists()


def test_control_library_checks_bounds_and_duration_before_the_claim(msd_spec, tmp_path):
    out = tmp_path / "out"
    for config in (ControlConfig(mpc=MPCConfig(u_min=(1.0,), u_max=(0.0,))),
                   ControlConfig(duration=1e-3)):
        with pytest.raises(UserError):
            compare(msd_spec, [], out, config)
        assert not out.exists()


def test_a_refusal_after_the_claim_removes_a_fresh_claim(msd_spec, tmp_path, capsys, monkeypatch):
    """Whatever refuses once ``out`` is claimed (here the controller's build), a new folder is
    removed and an empty one emptied."""
    compare_module = importlib.import_module("softpinn.bridge.control.compare")

    def refuse(*args, **kw):
        raise UserError("prediction model true: refused for the test")

    monkeypatch.setattr(compare_module, "MPC", refuse)
    new, empty = tmp_path / "new", tmp_path / "empty"
    empty.mkdir()
    for out in (new, empty):
        assert "refused for the test" in one_line_error(capsys, "control", msd_spec, "--out", out,
                                                  "--reference", "step", "--no-linear")
    assert not new.exists() and empty.is_dir() and not any(empty.iterdir())


def test_analyze_refuses_before_it_claims_out(run, msd_spec, tmp_path, capsys, monkeypatch):
    out = tmp_path / "an"
    err = one_line_error(capsys, "analyze", run, msd_spec, "--q", "nan", "0", "--out", out,
                   "--model-mismatch-ok")
    assert "--q: expected finite numbers" in err and not out.exists()
    # a refusal after the claim leaves nothing either
    from softpinn.bridge.cli import _analyze_run

    def refuse(*args, **kw):
        raise UserError("analysis: refused for the test")

    monkeypatch.setattr(_analyze_run, "analyze", refuse)
    err = one_line_error(capsys, "analyze", run, msd_spec, "--q", "0", "0", "--samples", "0",
                         "--out", out, "--model-mismatch-ok")
    assert "refused for the test" in err and not out.exists()


# --- 4. values that describe no arm --------------------------------------------------------

@pytest.mark.parametrize("argv, said", [
    (("task4", "--center", "0", "0", "-0.3"),
     "--center: dL1 = -0.3 makes segment 1's length L + dL1 = -0.1 m, not > 0"),
    (("task4", "--center", "0", "0", "-0.2"), "segment 1's length"),
    (("task5", "--center", "0", "0", "0", "0", "0", "-0.25"), "--center: dL2 = -0.25"),
    (("task3", "--center", "0", "-0.95", "--radius", "0.1"),
     "--radius: 0.1 takes dL1 to -1.05"),
    (("task4", "--center", "nan", "0", "0"), "got [nan, 0.0, 0.0]"),
    (("task4", "--horizon", "-3"), "--horizon: expected an integer >= 1"),
    (("task4", "--rate", "0"), "--rate"),
])
def test_control_refuses_values_that_describe_no_arm(tmp_path, capsys, argv, said):
    out = tmp_path / "out"
    assert said in one_line_error(capsys, "control", *argv, "--out", out)
    assert not out.exists()


@pytest.mark.parametrize("address, said", [
    ("localhost:99999", "port 99999"),
    ("localhost:0", "port 0"),
    ("localhost:65536", "port 65536"),
    ("localhost:http", "expected HOST:PORT"),
    (":1234", "expected HOST:PORT"),
])
def test_train_refuses_a_coordinator_that_is_no_address(data, tmp_path, capsys, address, said):
    out = tmp_path / "run"
    err = one_line_error(capsys, "train", data, "--model", "lagrangian", "--out", out,
                   "--coordinator", address, "--num-processes", "1", "--process-id", "0")
    assert "--coordinator" in err and said in err and not out.exists()


def test_import_out_that_is_a_folder_is_called_a_folder(tmp_path, capsys):
    for name in ("data.npz", "folder"):
        folder = tmp_path / name
        folder.mkdir()
        for force in ((), ("--force",)):
            err = one_line_error(capsys, "import", tmp_path / "x.csv", "--model", "task4", "--out",
                           folder, *force)
            assert "is a folder" in err and "--force" not in err
        assert folder.is_dir() and not any(folder.iterdir())
