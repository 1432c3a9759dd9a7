"""Multi-device training on one host (issue 21, part 1): --devices N splits each minibatch over
N devices (data parallel; XLA reduces the gradients) and gives the one-device parameters to
1e-10 in float64 with the same seed. Four CPU devices are made with XLA_FLAGS in a subprocess
(the flag must be set before JAX starts)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from datagen import make_dataset

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn._config import TrainConfig
from softpinn.learn._models import ModelConfig
from softpinn.learn.xlaflags import with_fast_compile

TESTS = Path(__file__).parent

SCRIPT = textwrap.dedent("""
    import json, os, sys
    os.environ["XLA_FLAGS"] += " --xla_force_host_platform_device_count=4"
    import jax
    jax.config.update("jax_enable_x64", True)
    sys.path.insert(0, sys.argv[2])
    import equinox as eqx
    import jax.numpy as jnp
    import numpy as np
    from datagen import make_dataset
    from softpinn.learn._config import TrainConfig
    from softpinn.learn._models import ModelConfig
    from softpinn.learn._members import stack
    from softpinn.learn._programs import PROGRAMS
    from softpinn.learn._train import load_run, train
    from pathlib import Path
    d = Path(sys.argv[1])
    data = make_dataset(d / "msd.npz", trajectories=4, duration=3.0)
    leaves, batches = {}, {}
    for dev in (1, 4):
        cfg = TrainConfig(model=ModelConfig(kind="lagrangian", n=2, m=1, mass=(8, 1),
                          potential=(8, 1), damping=(4, 1), input=(4, 1)), epochs=3,
                          batch_size=64, devices=dev)
        train(data, cfg, d / f"run{dev}")
        run = load_run(d / f"run{dev}")
        leaves[dev] = np.concatenate([np.ravel(x) for x in
                                      jax.tree.leaves(eqx.filter(run.model, eqx.is_array))])
        batches[dev] = json.loads((d / f"run{dev}" / "config.json").read_text())["pairs"]
    prog = list(PROGRAMS.entries.values())[-1]
    params = stack([eqx.filter(run.model, eqx.is_array)])
    hlo = prog._epoch_fn.lower(params, prog.init_opt(params), jnp.stack([jax.random.PRNGKey(0)]),
                               0, jnp.ones(1, bool), jnp.asarray(1e-3), prog.train)
    print(json.dumps({
        "device_count": jax.device_count(), "program_devices": prog.devices,
        "max_difference": float(np.max(np.abs(leaves[4] - leaves[1]))),
        "scale": float(np.max(np.abs(leaves[1]))),
        "all_reduce": "all-reduce" in hlo.compile().as_text(),
        "batch": {str(k): v["batch"] for k, v in batches.items()},
    }))
""")


def test_four_devices_give_the_one_device_parameters(tmp_path):
    env = dict(os.environ, XLA_FLAGS=with_fast_compile(None))  # no device count of ours
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), str(TESTS)],
                         capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["device_count"] == 4 and got["program_devices"] == 4
    assert got["all_reduce"]  # the batch really is split: XLA reduces the gradients
    assert got["batch"] == {"1": 64, "4": 64}
    assert got["max_difference"] < 1e-10 * max(1.0, got["scale"])


def test_more_devices_than_there_are_is_one_line(tmp_path, capsys):
    data = make_dataset(tmp_path / "msd.npz", trajectories=3, duration=2.0)
    model = ModelConfig(kind="lagrangian", n=2, m=1, mass=(4, 1), potential=(4, 1))
    from softpinn.learn._train import train

    with pytest.raises(UserError, match="devices: 2 asked for, 1 cpu device.*device_count"):
        train(data, TrainConfig(model=model, epochs=1, devices=2), tmp_path / "run")
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
    assert main(["train", str(data), "--model", "lagrangian", "--out", str(tmp_path / "r2"),
                 "--devices", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: --devices: 3 asked for")
    with pytest.raises(SystemExit) as exit_:
        main(["train", str(data), "--model", "lagrangian", "--out", str(tmp_path / "r3"),
              "--devices", "none"])
    assert exit_.value.code == 2
    assert "expected a count or 'all'" in capsys.readouterr().err
    # 0 means all, as the help says (here: the one CPU device)
    assert main(["train", str(data), "--model", "lagrangian", "--out", str(tmp_path / "r4"),
                 "--devices", "0", "--epochs", "1", "--quiet", "--mass", "4", "1",
                 "--potential", "4", "1"]) == 0
    with pytest.raises(SystemExit):
        main(["train", str(data), "--model", "lagrangian", "--out", str(tmp_path / "r5"),
              "--devices", "-1"])
    assert "expected a count >= 1, or 'all' (or 0), got -1" in capsys.readouterr().err
    with pytest.raises(UserError, match="devices: expected an integer >= 0"):
        TrainConfig(model=model, devices=-1)
    with pytest.raises(UserError, match="devices: 4 devices need a minibatch of at least 4"):
        TrainConfig(model=model, batch_size=2).batch_for(100, 4)
    assert TrainConfig(model=model).batch_for(10_000, 4) == 100
    assert TrainConfig(model=model, batch_size=66).batch_for(1000, 4) == 64  # rounded down
