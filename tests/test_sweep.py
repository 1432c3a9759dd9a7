"""softpinn sweep (issue 21, part 3): a 4-trial sweep through Ray Tune on a local Ray instance
with 2 CPUs (started once for the module), ASHA stopping the hopeless trials, every trial a
loadable run directory, the results table, plot and best link; the trials a space makes; bad
input as one line; without Ray, one line naming the extra."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from datagen import make_dataset, tiny_model_config

from softpinn.bridge.cli import main
from softpinn.bridge.sweep import (
    RAY_MISSING,
    Random,
    SweepConfig,
    make_trials,
    parse_space,
    sweep,
)
from softpinn.bridge.sweep.rows import trial_row
from softpinn.errors import UserError
from softpinn.learn import Stop, StopReason, TrainConfig, load_run
from softpinn.symbolic import ray_init

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("sweep-data") / "msd.npz", trajectories=5,
                        duration=4.0)


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance with 2 CPUs for the module (starting Ray takes seconds)."""
    import ray

    ray_init(ray, address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
             logging_level="ERROR")
    yield ray
    ray.shutdown()


def _base(**kw):
    return TrainConfig(**{"model": tiny_model_config("blackbox"), "epochs": 5, "batch_size": 32,
                          "lr": 1e-2, "test_trajectories": (4,), "checkpoint_every": 1000, **kw})


def _fails(capsys, argv) -> str:
    status = main(argv)
    err = capsys.readouterr().err.strip()
    assert status == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("softpinn: error: "), err
    return err


# ----------------------------------------------------------------------- without Ray at all


def test_sweep_without_ray_is_one_line(capsys, monkeypatch, data, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    err = _fails(capsys, ["sweep", str(data), "--model", "blackbox", "--out",
                          str(tmp_path / "s"), "--grid", "lr=1e-3,1e-2"])
    assert err == f"softpinn: error: {RAY_MISSING}"
    assert RAY_MISSING == "softpinn sweep needs Ray: pip install 'softpinn[ray]'"
    with pytest.raises(UserError, match="needs Ray"):
        sweep(data, _base(), {"lr": [1e-3]}, tmp_path / "s")
    assert not (tmp_path / "s").exists()


def test_bridge_imports_without_ray():
    code = ("import sys; sys.modules['ray'] = None\n"
            "import softpinn.bridge, softpinn.bridge.sweep, softpinn.bridge.cli\n"
            "softpinn.bridge.cli.build_parser()\n"
            "print('ray' in sys.modules and sys.modules['ray'] is not None)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True)
    assert out.stdout.strip() == "False"


# ----------------------------------------------------------------------- the space (no Ray)


def test_trials_of_a_grid_random_draws_and_seeds():
    space = {"lr": "log:1e-4:1e-2", "batch-size": [32, 64]}
    trials = make_trials(_base(), space, samples=3, seeds=2, random_seed=7)
    assert len(trials) == 3 * 2 * 2
    assert [t.seed for t in trials[:4]] == [0, 1, 0, 1]
    assert [t.config.batch_size for t in trials[:4]] == [32, 32, 64, 64]
    lrs = sorted({t.config.lr for t in trials})
    assert len(lrs) == 3 and all(1e-4 <= x <= 1e-2 for x in lrs)
    assert len({t.name for t in trials}) == len(trials)
    assert trials[1].name.startswith("001_lr=") and trials[1].name.endswith("_seed=1")
    again = make_trials(_base(), space, samples=3, seeds=2, random_seed=7)
    assert [t.config for t in again] == [t.config for t in trials]  # drawn from the seed
    assert parse_space(["batch-size=auto,64"], ["schedule=choice:cosine,constant"]) == {
        "batch_size": [None, 64], "schedule": Random("choice", choices=("cosine", "constant"))}
    r = Random("logint", 16, 256)
    import numpy as np

    draws = [r.draw(np.random.default_rng(s)) for s in range(200)]
    assert min(draws) >= 16 and max(draws) <= 256 and all(isinstance(d, int) for d in draws)


@pytest.mark.parametrize(("flags", "expected"), [
    (["--grid", "foo=1,2"], "--grid: unknown setting 'foo' (settings: epochs, batch-size"),
    (["--grid", "lr=abc"], "--grid lr=abc: expected a number"),
    (["--grid", "epochs=2.5"], "--grid epochs=2.5: expected an integer"),
    (["--grid", "lr=-1"], "trial lr=-1: lr: expected a finite number > 0, got -1.0"),
    (["--grid", "schedule=cosine,bogus"], "--grid schedule=bogus: expected one of cosine"),
    (["--grid", "lr"], "--grid lr: expected SETTING=VALUES"),
    (["--random", "lr=log:0:1"], "--random lr=log:0:1: a log range needs LOW > 0"),
    (["--random", "lr=gauss:1:2"], "--random lr=gauss:1:2: expected KIND:LOW:HIGH"),
    (["--random", "batch-size=log:16:64"], "batch-size is an integer; use int: or logint:"),
    (["--grid", "test-trajectories=1"], "test-trajectories cannot be swept: the trials are "
     "ranked by their test loss"),
    (["--grid", "seeds=1,2"], "seeds cannot be swept: a trial trains one seed"),
    (["--grid", "lr=1e-3", "--grid", "lr=1e-2"], "lr is given twice"),
    (["--grid", "lr=1e-3", "--lr", "1e-2"], "--lr is fixed for every trial and swept"),
    (["--grid", "lr=1e-3", "--samples", "3"], "samples: random draws need a random range"),
    (["--grid", "seed=1,2", "--seeds", "2"], "seed: give seeds=K (--seeds K) or sweep seed"),
    (["--grid", "lr=1e-3", "--address", "127.0.0.1:1"],
     "--address: nothing answers at 127.0.0.1:1"),
    (["--grid", "lr=1e-3", "--scheduler", "asha", "--grace-period", "9"],
     "--grace-period: 9 is more than the epochs (5)"),
])
def test_bad_input_is_one_line(capsys, data, tmp_path, flags, expected):
    err = _fails(capsys, ["sweep", str(data), "--model", "blackbox", "--epochs", "5",
                          "--out", str(tmp_path / "s"), *flags])
    assert expected in err, err


def test_out_holding_other_files_is_refused(capsys, data, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    err = _fails(capsys, ["sweep", str(data), "--model", "blackbox", "--out",
                          str(tmp_path / "mine"), "--grid", "lr=1e-3,1e-2"])
    assert "already holds files softpinn did not write" in err
    assert sorted(p.name for p in (tmp_path / "mine").iterdir()) == ["notes.txt"]


def test_sweep_config_refuses_bad_settings():
    for kw, expected in ((dict(scheduler="pbt"), "scheduler: expected one of asha, none"),
                         (dict(metric="loss"), "metric: expected one of best_test_loss"),
                         (dict(cpus_per_trial=0), "cpus_per_trial: expected a number > 0"),
                         (dict(gpus_per_trial=-1), "gpus_per_trial: expected a number >= 0"),
                         (dict(max_concurrent=0), "max_concurrent: expected an integer >= 1"),
                         (dict(reduction_factor=1), "reduction_factor: expected a number > 1"),
                         (dict(address="auto", num_cpus=2), "num_cpus: sizes a local Ray")):
        with pytest.raises(UserError, match=re.escape(expected)):
            SweepConfig(**kw)
    with pytest.raises(UserError, match="config: expected a SweepConfig"):
        sweep("data.npz", _base(), {"lr": [1e-3]}, "out", {"scheduler": "none"})


# ----------------------------------------------------------------------- a trial's status


class _Result:
    """What a trial's row reads of a ``ray.tune.Result``."""

    def __init__(self, **metrics):
        self.metrics, self.error = metrics, None


def _row(tmp_path, metrics: dict, scheduler="asha", **last):
    trial = make_trials(_base(), {})[0]
    tdir = tmp_path / "trials" / trial.name
    tdir.mkdir(parents=True, exist_ok=True)
    (tdir / "metrics.json").write_text(json.dumps({"best_test_loss": 0.5, "epochs_run": 3,
                                                   **metrics}))
    (tdir / "model.eqx").write_bytes(b"")
    return trial_row(trial, _Result(**last), True, tmp_path, scheduler)


@pytest.mark.parametrize(("reason", "status", "early"), [
    ("completed", "completed", False),
    ("patience", "early stop (patience)", True),
    ("overfit", "early stop (overfit)", True),
    ("target", "reached the target loss", False),
    ("diverged", "diverged", False),
    ("interrupted", "stopped by ASHA at epoch 3", True),
    ("running", "stopped by ASHA at epoch 3", True),
])
def test_a_trials_status_is_its_stop_reason_not_the_wording(tmp_path, reason, status, early):
    """The row reads the run's stop_reason: a sentence worded otherwise changes nothing."""
    row = _row(tmp_path, {"stop_reason": reason, "stopped": "worded some other way"})
    assert (row["status"], row["stopped_early"]) == (status, early)


@pytest.mark.parametrize(("sentence", "reason"), [
    ("completed 50 epochs", StopReason.COMPLETED),
    ("early stop at epoch 7 (patience 3)", StopReason.PATIENCE),
    ("early stop at epoch 9 (overfit: test loss above 2x its best, 0.1 at epoch 4, for 3 "
     "evaluations)", StopReason.OVERFIT),
    ("reached test loss 0.001 <= 0.002 at epoch 5 (lbfgs)", StopReason.TARGET),
    ("diverged at epoch 4 (adamw)", StopReason.DIVERGED),
    ("interrupted at epoch 3 (--resume continues)", StopReason.INTERRUPTED),
    ("running", StopReason.RUNNING),
    ("something else", StopReason.UNKNOWN),
])
def test_old_run_folders_without_a_stop_reason_still_read(tmp_path, sentence, reason):
    """A run folder written before stop_reason: the reason its sentence states (the one
    fallback), and the sweep's status from it as before."""
    assert Stop.read({"stopped": sentence}) == Stop(reason, sentence)
    assert StopReason.parse(None, sentence) is reason
    row = _row(tmp_path, {"stopped": sentence}, scheduler="none")
    expected = {StopReason.PATIENCE: "early stop (patience)",
                StopReason.OVERFIT: "early stop (overfit)",
                StopReason.TARGET: "reached the target loss",
                StopReason.DIVERGED: "diverged", StopReason.INTERRUPTED: "interrupted",
                StopReason.RUNNING: "interrupted"}.get(reason, "completed")
    assert row["status"] == expected


# ----------------------------------------------------------------------- a sweep on Ray


def test_four_trial_sweep_with_asha(local_ray, capsys, data, tmp_path):
    """lr 1e-2 against a hopeless 1e-7, batch 32 and 64; the hopeless trials come last in the
    grid and the trials run one at a time, so the good ones have reached every rung before the
    hopeless ones start, however loaded the machine: ASHA stops both at their first rung. (Two
    at a time, a good trial could lag behind a hopeless one on a busy machine, and ASHA then
    had nothing to stop it against.) Every trial is a run directory; the best one is linked."""
    import signal

    out = tmp_path / "sweep"
    sigint = signal.getsignal(signal.SIGINT)
    status = main(["sweep", str(data), "--model", "blackbox", "--out", str(out),
                   "--grid", "lr=1e-2,1e-7", "--grid", "batch-size=32,64", "--epochs", "5",
                   "--hidden", "16", "2", "--test-trajectories", "4", "--checkpoint-every",
                   "1000", "--grace-period", "1", "--max-concurrent", "1", "--quiet",
                   "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    # Tune installs a SIGINT handler of its own; Ctrl-C after the sweep is the caller's again
    assert signal.getsignal(signal.SIGINT) is sigint
    printed = json.loads(captured.out)
    rows = printed["results"]
    assert len(rows) == 4 and printed["trials"] == 4
    by_lr = {lr: [r for r in rows if r["settings"]["lr"] == lr] for lr in (1e-2, 1e-7)}
    for r in by_lr[1e-7]:  # hopeless: stopped at the first rung
        assert r["stopped_early"] and r["status"].startswith("stopped by ASHA"), r
        assert r["epochs_run"] < 5, r
    assert any(not r["stopped_early"] and r["epochs_run"] == 5 for r in by_lr[1e-2]), rows
    best = printed["best"]
    assert best["settings"]["lr"] == 1e-2 and best == rows[0]
    assert best["best_test_loss"] == min(r["best_test_loss"] for r in rows)

    # every trial: a run directory load_run reads, trained with its settings
    for r in rows:
        run = load_run(out / r["path"])
        assert run.train_config.lr == r["settings"]["lr"]
        assert run.train_config.batch_size == r["settings"]["batch_size"]
        assert run.train_config.epochs == 5 and run.seed == 0
    # the best link, in results.json and results.md too
    assert (out / "best").is_symlink()
    assert (out / "best").resolve() == (out / best["path"]).resolve()
    assert load_run(out / "best").train_config.lr == 1e-2
    info = json.loads((out / "results.json").read_text())
    assert info["best"]["path"] == best["path"] and info["best"]["link"] == "best"
    assert Path(info["best"]["dir"]) == (out / best["path"]).resolve()
    assert [r["trial"] for r in info["results"]] == [r["trial"] for r in rows]
    md = (out / "results.md").read_text()
    assert f"[{best['path']}]({best['path']}/)" in md and "(best/)" in md
    assert md.count("| yes |") == sum(r["stopped_early"] for r in rows)
    assert "![best test loss against the swept settings](sweep.png)" in md
    with open(out / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [t["trial"] for t in table] == [r["trial"] for r in rows]
    assert set(table[0]) >= {"lr", "batch_size", "seed", "best_test_loss", "epochs_run",
                             "stopped_early", "status", "seconds", "wall_seconds", "path"}
    assert float(table[0]["best_test_loss"]) == best["best_test_loss"]
    assert (out / "sweep.png").read_bytes().startswith(b"\x89PNG")
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["command"] == "sweep"
    assert {"results.csv", "results.json", "results.md", "sweep.png"} <= set(manifest["files"])


def test_a_failing_trial_is_a_row(local_ray, data, tmp_path):
    """A trial whose settings the run refuses (more devices than there are) is a row with the
    one-line error, not a traceback; with no trial left there is no best link."""
    res = sweep(data, _base(devices=3), {"lr": [1e-2]}, tmp_path / "s",
                SweepConfig(scheduler="none"))
    (row,) = res.rows
    assert row["status"].startswith("error: devices: 3 asked for"), row
    assert row["path"] is None and res.best is None and res.best_dir is None
    assert not (tmp_path / "s" / "best").exists()
    md = (tmp_path / "s" / "results.md").read_text()
    assert "No trial finished with a finite test loss" in md
    assert (tmp_path / "s" / "sweep.png").is_file()
