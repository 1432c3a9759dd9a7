"""Outputs appear whole or not at all (issue 15): ``derive`` builds its folder in a temporary
sibling and renames it into place; ``simulate`` writes every file (the data set and its
resampled siblings) to temporary siblings and installs them together. An interrupted or killed
command leaves nothing that blocks or pollutes the rerun; a sibling of a dead run is removed by
the next one. Before the fix, ``derive`` killed half-way left a partial folder that the rerun
refused ("not empty ... use --force"), and ``simulate`` interrupted between files left the first
one, which the rerun refused ("file exists")."""

from __future__ import annotations

import json
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen import _generate as generate
from softpinn.symbolic.simulation import _datafile as datafile
from softpinn.symbolic.simulation._datafile import read_dataset


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def hanging_compiler(tmp_path: Path) -> Path:
    """A compiler that signals it started (``started``) and then hangs."""
    script = tmp_path / "hangcc"
    script.write_text(f"#!/bin/sh\necho $$ > {tmp_path}/started\nexec sleep 30\n")
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return script


def wait_for(path: Path, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    while not (path.is_file() and path.read_text().strip()):
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.02)


CLI = "import sys\nfrom softpinn.bridge.cli import main\nsys.exit(main(sys.argv[1:]))\n"


def test_derive_killed_half_way_leaves_nothing_that_blocks_the_rerun(tmp_path, capsys):
    out = tmp_path / "d1"
    cc = hanging_compiler(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-c", CLI, "derive", "task1", "--out", str(out), "--compiler", str(cc)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        wait_for(tmp_path / "started")  # the C source and CasADi files are written by now
        proc.kill()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not out.exists()
    # its partial folder, and its claim's lock file (softpinn.locks: not held, nothing blocks)
    assert sorted(p.name.startswith(".d1.partial-") for p in tmp_path.glob(".d1*")) == [
        False, True] and (tmp_path / ".d1.lock").is_file()
    status, _, err = run(capsys, "derive", "task1", "--out", out)  # no --force needed
    assert status == 0, err
    assert (out / "summary.json").is_file() and (out / "softpinn_eom.so").is_file()
    assert not list(tmp_path.glob(".d1*"))  # the dead run's sibling is gone


def test_derive_interrupted_leaves_the_folder_as_it_was(tmp_path, capsys, monkeypatch):
    out = tmp_path / "d2"
    assert run(capsys, "derive", "task1", "--out", out)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(generate, "compile_c", interrupted)
    status, _, err = run(capsys, "derive", "task1", "--out", out)
    assert status == 130 and "interrupted" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert not list(tmp_path.glob(".d2*"))
    # interrupted before anything existed: nothing at all
    status, _, _ = run(capsys, "derive", "task1", "--out", tmp_path / "new")
    assert status == 130 and not list(tmp_path.glob("*new*"))


def test_derive_over_an_earlier_output_keeps_the_users_files(tmp_path, capsys, monkeypatch):
    """Into an earlier derive output the files are replaced; the user's own files stay, files
    the earlier summary listed and this output has not (the library, without a compiler) go."""
    out = tmp_path / "d3"
    assert run(capsys, "derive", "task1", "--out", out)[0] == 0
    (out / "notes.txt").write_text("mine")
    monkeypatch.setenv("CC", str(tmp_path / "no-cc"))
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))
    status, _, err = run(capsys, "derive", "task1", "--out", out)
    assert status == 0 and "no C compiler found" in err
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "softpinn_eom.so").exists()
    assert json.loads((out / "summary.json").read_text())["library"] is None


def two_rate_spec(tmp_path: Path) -> Path:
    spec = tmp_path / "msd.toml"
    spec.write_text(
        'kind = "mass-spring-damper"\nmasses = [1.0, 1.0]\nsprings = [1.0, 1.0]\n'
        'dampers = [0.1, 0.0]\nactuation = "generalized"\n'
        "[data]\nrates = [25.0, 50.0]\nduration = 0.4\ntrajectories = 2\n"
        "q0_low = [-0.1, -0.1]\nq0_high = [0.1, 0.1]\n"
    )
    return spec


def test_simulate_interrupted_between_files_writes_none(tmp_path, capsys, monkeypatch):
    spec = two_rate_spec(tmp_path)
    out = tmp_path / "m.npz"
    calls = []
    savez = np.savez

    def interrupted_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return savez(*args, **kwargs)

    monkeypatch.setattr(datafile.np, "savez", interrupted_second)
    status, _, _ = run(capsys, "simulate", spec, "--out", out, "--quiet", "--no-compile")
    assert status == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["msd.toml"]
    monkeypatch.undo()
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "cache"))
    status, _, err = run(capsys, "simulate", spec, "--out", out, "--quiet", "--no-compile")
    assert status == 0, err
    assert read_dataset(out).meta["rate"] == 50.0
    assert read_dataset(tmp_path / "m_25hz.npz").meta["rate"] == 25.0
    assert not list(tmp_path.glob(".*"))


def test_a_dead_runs_dataset_sibling_is_removed_a_live_ones_kept(tmp_path):
    data = datafile.DatasetArrays(
        t=np.zeros(2), q=np.zeros((2, 1)), qd=np.zeros((2, 1)), qdd=np.zeros((2, 1)),
        p=np.zeros((2, 1)), u=np.zeros((2, 0)), traj=np.zeros(2, dtype=np.int64), meta={},
    )
    done = subprocess.Popen(["true"])
    done.wait()
    host = outputs.owner_tag().split("@", 1)[1]
    dead = tmp_path / f".d.npz.partial-{done.pid}@{host}"
    alive = tmp_path / f".d.npz.partial-1@{host}"  # pid 1 runs as long as the machine
    dead.write_bytes(b"half")
    alive.write_bytes(b"being written")
    datafile.write_dataset(tmp_path / "d.npz", data)
    assert not dead.exists() and alive.exists()
    assert len(read_dataset(tmp_path / "d.npz")) == 2


def test_dataset_meta_must_be_strict_json(tmp_path):
    data = datafile.DatasetArrays(
        t=np.zeros(2), q=np.zeros((2, 1)), qd=np.zeros((2, 1)), qdd=np.zeros((2, 1)),
        p=np.zeros((2, 1)), u=np.zeros((2, 0)), traj=np.zeros(2, dtype=np.int64),
        meta={"simulation": {"rtol": float("nan")}},
    )
    with pytest.raises(UserError, match=r"simulation\.rtol is not a finite number"):
        datafile.write_dataset(tmp_path / "d.npz", data)
    assert not list(tmp_path.iterdir())
