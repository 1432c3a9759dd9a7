"""Training on several processes (issue 21, part 2): two processes on localhost join through
jax.distributed (--coordinator/--num-processes/--process-id, Gloo collectives on CPU), split
every minibatch over both, and give the one-process parameters; process 0 alone writes the run
directory."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
from datagen import make_dataset

from softpinn.bridge.cli import main
from softpinn.learn._train import load_run
from softpinn.learn.xlaflags import with_fast_compile

TRAIN = ["--model", "lagrangian", "--epochs", "3", "--batch-size", "64", "--width", "8",
         "--depth", "1", "--quiet", "--json"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _leaves(run: Path) -> np.ndarray:
    import equinox as eqx

    model = load_run(run).model
    return np.concatenate([np.ravel(x) for x in jax.tree.leaves(eqx.filter(model, eqx.is_array))])


def test_two_processes_train_the_one_process_model(tmp_path):
    data = make_dataset(tmp_path / "msd.npz", trajectories=4, duration=3.0)
    port = _free_port()
    env = dict(os.environ, XLA_FLAGS=with_fast_compile(None))  # no device count of ours
    cli = "import sys; from softpinn.bridge.cli import main; sys.exit(main(sys.argv[1:]))"
    cmd = [sys.executable, "-c", cli, "train", str(data), *TRAIN,
           "--out", str(tmp_path / "two"), "--devices", "all",
           "--coordinator", f"localhost:{port}", "--num-processes", "2"]
    procs = [subprocess.Popen([*cmd, "--process-id", str(i)], env=env, cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in (0, 1)]
    outs = [p.communicate(timeout=600) for p in procs]
    for p, (_out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    # process 0 reports (Gloo's C++ prints its connection line to stdout)
    last = lambda out: [line for line in out.splitlines() if not line.startswith("[Gloo]")]
    assert last(outs[0][0])[-1].startswith("{") and last(outs[1][0]) == []
    assert main(["train", str(data), *TRAIN, "--out", str(tmp_path / "one")]) == 0
    one, two = _leaves(tmp_path / "one"), _leaves(tmp_path / "two")
    assert np.max(np.abs(one - two)) < 1e-10 * max(1.0, float(np.max(np.abs(one))))
    # only process 0's run directory exists; the other's private copy is gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["msd.npz", "one", "two"]


def test_process_flags_are_checked(tmp_path, capsys):
    data = make_dataset(tmp_path / "msd.npz", trajectories=3, duration=2.0)
    for extra, message in (
        (["--coordinator", "localhost:1"], "go together"),
        (["--coordinator", "nowhere", "--num-processes", "2", "--process-id", "0"],
         "expected HOST:PORT"),
        (["--coordinator", "localhost:1", "--num-processes", "2", "--process-id", "2"],
         "process-id: expected an integer in [0, 2)"),
        (["--cluster", "--process-id", "0"], "not both"),
    ):
        assert main(["train", str(data), *TRAIN, "--out", str(tmp_path / "r"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
