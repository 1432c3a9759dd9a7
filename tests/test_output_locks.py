"""Two writers, one output (issue 44): every command that writes a folder or a file that takes a
while holds an exclusive claim on it (:mod:`softpinn.locks`), so a second writer gets one line,
exit 2, naming the process that holds it, and a killed holder never blocks the next run; and a
killed compile's build folder is removed by the next start that opens the code cache."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from softpinn import locks
from softpinn.errors import UserError

#: a process that takes the claim on argv[1] for the command argv[2], says so, and sleeps
HOLDER = textwrap.dedent("""
    import sys, time
    from softpinn import locks
    from softpinn.errors import UserError
    try:
        locks.hold(sys.argv[1], sys.argv[2])
    except UserError as exc:
        print(exc, flush=True)
        sys.exit(2)
    print("held", flush=True)
    time.sleep(float(sys.argv[3]))
""")
CLI = "import sys; from softpinn.bridge.cli import main; sys.exit(main(sys.argv[1:]))"


def _holder(target: Path, command: str = "train", seconds: float = 60.0) -> subprocess.Popen:
    """A process holding ``target``'s claim (returned once it holds it)."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(target), command, str(seconds)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def _end(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.communicate()


def test_two_processes_one_wins_the_other_names_it(tmp_path):
    out = tmp_path / "same0"
    procs = [subprocess.Popen([sys.executable, "-c", HOLDER, str(out), "train", "1.5"],
                              stdout=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=60), p.communicate()[0].strip()) for p in procs]
    assert sorted(code for code, _ in results) == [0, 2]
    winner = next(p for p, (code, _) in zip(procs, results, strict=True) if code == 0)
    refused = next(text for code, text in results if code == 2)
    assert len(refused.splitlines()) == 1
    assert f"softpinn train (process {winner.pid}@" in refused and "is writing there" in refused
    assert not list(tmp_path.iterdir())  # the lock file went with its holder


def test_a_killed_holder_never_blocks_and_a_live_one_always_does(tmp_path):
    out = tmp_path / "run"
    proc = _holder(out)
    try:
        with pytest.raises(UserError, match=rf"softpinn train \(process {proc.pid}@"):
            locks.hold(out, "train")
        with pytest.raises(UserError, match="is writing there"):
            locks.check_free(out)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert (tmp_path / ".run.lock").exists()  # left by the killed process, but not held
    locks.check_free(out)
    with locks.scope():
        assert locks.hold(out, "analyze") and not locks.hold(out, "analyze")  # re-entrant
        owner = json.loads((tmp_path / ".run.lock").read_text())
        assert owner["pid"] == os.getpid() and owner["command"] == "analyze"
    assert not list(tmp_path.iterdir())  # given up at the end of the scope


def test_a_refused_claim_leaves_nothing_and_folders_made_for_it_go(tmp_path):
    from softpinn.bridge.base import outputs

    out = tmp_path / "new" / "deep" / "out"
    with locks.scope():
        locks.hold(out, "derive")
        assert (tmp_path / "new" / "deep" / ".out.lock").is_file()
    assert not (tmp_path / "new").exists()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="already holds"):
        outputs.claim(tmp_path / "mine", "analyze")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


def test_an_output_folder_claim_is_exclusive(tmp_path):
    from softpinn.bridge.base import outputs

    out = tmp_path / "o"
    proc = _holder(out, "reproduce")
    try:
        with pytest.raises(UserError, match=rf"^out: .*o: softpinn reproduce \(process "
                                            rf"{proc.pid}@[^)]*\) is writing there"):
            outputs.claim(out, "reproduce")
        assert not out.exists()
    finally:
        _end(proc)
    with locks.scope():
        assert outputs.claim(out, "reproduce") == out
        assert locks.holds(out)
    assert not locks.holds(out)


def test_a_dataset_file_is_claimed_while_it_is_written(tmp_path):
    import numpy as np

    from softpinn.symbolic.simulation import _datafile as datafile

    data = datafile.DatasetArrays(
        t=np.zeros(2), q=np.zeros((2, 1)), qd=np.zeros((2, 1)), qdd=np.zeros((2, 1)),
        p=np.zeros((2, 1)), u=np.zeros((2, 0)), traj=np.zeros(2, dtype=np.int64), meta={},
    )
    path = tmp_path / "d.npz"
    proc = _holder(path, "simulate")
    try:
        with pytest.raises(UserError, match=rf"softpinn simulate \(process {proc.pid}@"):
            datafile.write_dataset(path, data)
        assert not path.exists()
    finally:
        _end(proc)
    datafile.write_dataset(path, data)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npz"]  # the lock file went


@pytest.mark.parametrize("argv", [
    ["simulate", "task1", "--trajectories", "1", "--duration", "0.5", "--no-compile"],
    ["derive", "task1"],
])
def test_cli_commands_refuse_a_held_output_in_one_line(tmp_path, capsys, argv):
    from softpinn.bridge.cli import main

    out = tmp_path / ("d.npz" if argv[0] == "simulate" else "eom")
    proc = _holder(out, argv[0])
    try:
        assert main([*argv, "--out", str(out)]) == 2
    finally:
        _end(proc)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("softpinn: error: --out: ") and f"(process {proc.pid}@" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".eom.lock" if argv[0] == "derive"
                                                          else ".d.npz.lock"]  # the killed one's


def test_two_trains_on_one_folder_one_is_refused_the_other_run_complete(tmp_path):
    from datagen import make_dataset

    data = make_dataset(tmp_path / "msd.npz", trajectories=5, duration=3.0)
    out = tmp_path / "same0"

    def start(lr):
        return subprocess.Popen(
            [sys.executable, "-c", CLI, "train", str(data), "--model", "blackbox", "--hidden",
             "8", "1", "--epochs", "100", "--lr", lr, "--quiet", "--out", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)

    procs = {lr: start(lr) for lr in ("0.01", "0.02")}
    done = {lr: (p.wait(timeout=300), *p.communicate()) for lr, p in procs.items()}
    codes = sorted(code for code, _, _ in done.values())
    assert codes == [0, 2], {lr: err[-2000:] for lr, (_, _, err) in done.items()}
    won = next(lr for lr, (code, _, _) in done.items() if code == 0)
    lost = next(lr for lr in done if lr != won)
    err = done[lost][2].strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: --out: "), err
    assert f"softpinn train (process {procs[won].pid}@" in err[0]
    assert "run directory: " in done[won][1]
    config = json.loads((out / "config.json").read_text())
    assert config["train"]["lr"] == float(won)  # the winner's run, whole
    manifest = json.loads((out / "manifest.json").read_text())["files"]
    for name in ("config.json", "model.eqx", "checkpoint.eqx", "metrics.json", "history.csv"):
        assert name in manifest and (out / name).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["msd.npz", "same0"]


def test_a_dead_compiles_build_folder_goes_when_the_cache_is_opened(tmp_path, monkeypatch):
    from softpinn.files import owner_tag
    from softpinn.symbolic.codegen import _codegen as codegen

    cache = tmp_path / "cache"
    key = cache / "0123abcd"
    key.mkdir(parents=True)
    done = subprocess.Popen(["true"])
    done.wait()
    host = owner_tag().split("@", 1)[1]
    dead = key / f".build-{done.pid}@{host}-abc123"
    live = key / f".build-{os.getpid()}@{host}-def456"
    dead.mkdir()
    live.mkdir()
    monkeypatch.setattr(codegen, "_opened", set())
    assert codegen.open_cache(cache) == cache.absolute()
    assert not dead.exists() and live.is_dir()


def test_a_run_served_from_the_cache_removes_a_killed_compiles_leftovers(tmp_path, monkeypatch):
    import casadi as ca

    from softpinn.files import owner_tag
    from softpinn.symbolic.codegen import _codegen as codegen

    assert codegen.find_compiler(None) is not None, "the test machine has a C compiler"
    x = ca.SX.sym("x")
    fns = {"f": ca.Function("lockstest_f", [x], [ca.sin(x) * 2])}
    cache = tmp_path / "cache"
    first = codegen.compile_functions(fns, directory=cache)
    assert first.compiled and not first.from_cache
    done = subprocess.Popen(["true"])
    done.wait()
    dead = first.library.parent / f".build-{done.pid}@{owner_tag().split('@', 1)[1]}-a1b2c3"
    dead.mkdir()
    (dead / "half.c").write_text("/* killed while compiling */")
    monkeypatch.setattr(codegen, "_opened", set())  # a new process's first opening
    again = codegen.compile_functions(fns, directory=cache)
    assert again.from_cache and not dead.exists()
    assert float(again.functions["f"](0.5)) == pytest.approx(2 * float(ca.sin(0.5)))
