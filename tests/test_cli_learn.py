"""``softpinn train`` / ``softpinn predict`` through ``bridge.cli.main``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from datagen import make_dataset, simulate, write

from softpinn.bridge.cli import main

# the same settings as tests/datagen.py:blackbox_train_config, so the program compiles once
TRAIN = [
    "--model", "blackbox", "--hidden", "16", "2", "--epochs", "12", "--batch-size", "64",
    "--lr", "1e-2", "--test-trajectories", "4", "--checkpoint-every", "1000", "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("cli") / "msd.npz", trajectories=5, duration=4.0)


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["train", str(data), "--out", str(out), *TRAIN]) == 0
    return out


def _error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("softpinn: error: ")
    return err[0]


def test_train_writes_run_dir(run, capsys):
    for name in ("config.json", "model.eqx", "checkpoint.eqx", "history.csv", "metrics.json",
                 "loss.png"):  # fmt: skip
        assert (run / name).is_file(), name
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["model"]["kind"] == "blackbox" and cfg["model"]["hidden"] == [16, 2]
    assert cfg["train"]["epochs"] == 12 and cfg["split"]["test"] == [4]
    assert len(cfg["dataset"]["sha256"]) == 64


def test_train_holds_out_the_split_the_file_records(data, tmp_path, capsys):
    """Without a split on the command line, the test trajectories are the ones the file records
    (simulate's spec, import --test-trajectories), and the summary says which and why."""
    arrays = dict(np.load(data))
    meta = json.loads(str(arrays.pop("meta")))
    meta["splits"] = {"train": [0, 1, 2], "test": [3, 4]}
    recorded = write(tmp_path / "split.npz", arrays, meta)
    flags = [f for f in TRAIN if f not in ("--test-trajectories", "4")]
    capsys.readouterr()
    assert main(["train", str(recorded), "--out", str(tmp_path / "r"), *flags]) == 0
    assert "held out: trajectories 3, 4 (the test split the file records)" in (
        capsys.readouterr().out)
    assert json.loads((tmp_path / "r" / "config.json").read_text())["split"]["test"] == [3, 4]
    # a split given on the command line wins, and is said to be given
    assert main(["train", str(recorded), "--out", str(tmp_path / "g"), *TRAIN]) == 0
    assert "held out: trajectory 4 (given)" in capsys.readouterr().out
    # one trajectory: nothing to hold out, and the summary says so
    one = {k: v[arrays["traj"] == 0] for k, v in arrays.items()}
    single = write(tmp_path / "one.npz", one, {"spec": {"name": "one"}})
    assert main(["train", str(single), "--out", str(tmp_path / "o"), *flags]) == 0
    assert "held out: nothing (the file has one trajectory" in capsys.readouterr().out


def test_train_json_resume_and_force(data, run, capsys, tmp_path):
    out = tmp_path / "r"
    assert main(["train", str(data), "--out", str(out), *TRAIN, "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["seeds"] == [0] and m["best_test_loss"]["mean"] > 0
    # same options as the module run: identical result
    ref = json.loads((run / "metrics.json").read_text())
    assert m["best_test_loss"]["mean"] == ref["best_test_loss"]
    assert main(["train", str(data), "--out", str(out), *TRAIN]) == 2
    assert "already exists and is not empty; use --force" in _error_line(capsys)
    # refused before any work: no progress bar before the one line
    loud = [f for f in TRAIN if f != "--quiet"]
    assert main(["train", str(data), "--out", str(out), *loud]) == 2
    assert "already exists and is not empty; use --force" in _error_line(capsys)
    assert main(["train", str(data), "--out", str(out), "--resume", "--quiet"]) == 0
    assert main(["train", str(data), "--out", str(out), *TRAIN, "--force"]) == 0


def test_predict_json(run, data, capsys, tmp_path):
    capsys.readouterr()
    png = tmp_path / "p.png"
    args = ["predict", str(run), str(data), "--horizon", "2", "--json", "--plot", str(png)]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("one_step_error", "rollout_error_mean", "rollout_error_std", "horizon",
                "trajectories"):  # fmt: skip
        assert key in out
    assert out["horizon"] == 2.0 and out["trajectories"] == [4] and png.is_file()
    assert set(out["one_step_error"]) >= {"mean", "std"}
    args = ["predict", str(run), str(data), "--horizon", "2", "--reset-every", "0.5",
            "--dt", "0.025", "--trajectories", "all"]  # fmt: skip
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "rollout error (2 s, reset every 0.5 s, dt 0.025 s)" in text
    assert "over 5 trajectories" in text


@pytest.mark.parametrize(
    "change, message",
    [
        ("nan", "'q' holds 1 NaN/inf value(s)"),
        ("time", "time must increase within a trajectory"),
        ("shape", "'p' must have shape"),
        ("missing", "missing key(s) qdd"),
    ],
)
def test_train_bad_dataset_one_line(change, message, tmp_path, capsys):
    a = simulate("msd", trajectories=2, duration=1.0)
    if change == "nan":
        a["q"][3, 0] = np.nan
    elif change == "time":
        a["t"][4] = a["t"][2]
    elif change == "shape":
        a["p"] = a["p"][:, :1]
    else:
        del a["qdd"]
    path = write(tmp_path / "bad.npz", a)
    assert main(["train", str(path), "--out", str(tmp_path / "r"), *TRAIN]) == 2
    line = _error_line(capsys)
    assert message in line and "bad.npz" in line


def test_train_mass_init_from_data(tmp_path, capsys):
    from softpinn.learn._data import load_dataset, mass_scale

    a = simulate("msd", trajectories=3, duration=1.0)
    a["p"][a["traj"] == 2] *= 10.0  # a held-out trajectory that would move the scale
    data = write(tmp_path / "d.npz", a)
    out = tmp_path / "h"
    args = ["--model", "hamiltonian", "--width", "8", "--depth", "1", "--epochs", "1",
            "--test-trajectories", "2", "--quiet", "--mass-init", "data"]  # fmt: skip
    assert main(["train", str(data), "--out", str(out), *args]) == 0
    cfg = json.loads((out / "config.json").read_text())
    loaded = load_dataset(data)
    # from the training trajectories only, as the pipelines take it: the test one stays unseen
    expected = mass_scale(loaded, "hamiltonian", [0, 1])
    assert cfg["model"]["mass_init"] == pytest.approx(expected, rel=1e-12)
    assert expected != pytest.approx(mass_scale(loaded, "hamiltonian"), rel=1e-3)


def test_cli_user_errors(run, data, tmp_path, capsys):
    assert main(["train", str(data), "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert "--model is required" in _error_line(capsys)
    assert main(["train", str(data), "--out", str(tmp_path / "x"), *TRAIN, "--epochs", "0"]) == 2
    # the library names the field (epochs: ...), the CLI the flag the user typed
    assert "--epochs: expected an integer >= 1, got 0" in _error_line(capsys)
    assert main(["train", str(data), "--out", str(tmp_path / "x"), *TRAIN, "--lr", "nan"]) == 2
    assert "--lr: expected a finite number > 0, got nan" in _error_line(capsys)
    assert main(["train", str(data), "--out", str(tmp_path / "x"), *TRAIN,
                 "--target-loss", "0"]) == 2
    assert "--target-loss: expected a number > 0, got 0.0" in _error_line(capsys)
    assert not (tmp_path / "x").exists()
    assert main(["predict", str(run), str(data), "--horizon", "-1"]) == 2
    assert "--horizon: expected a positive number of seconds" in _error_line(capsys)
    assert main(["predict", str(tmp_path / "nope"), str(data), "--horizon", "1"]) == 2
    assert "no such directory" in _error_line(capsys)
    pend = make_dataset(tmp_path / "pend.npz", "pendulum", trajectories=2, duration=1.0)
    assert main(["predict", str(run), str(pend), "--horizon", "1"]) == 2
    assert "model has n=2 coordinates, the file has n=1" in _error_line(capsys)
    assert main(["predict", str(run), str(data), "--horizon", "1", "--trajectories", "x"]) == 2
    assert "--trajectories takes" in _error_line(capsys)
    assert main(["train", str(data), "--out", str(tmp_path / "x"), *TRAIN, "--mass-init",
                 "1"]) == 2  # fmt: skip
    assert "--mass-init applies to physics models, not --model blackbox" in _error_line(capsys)
    ham = ["--model", "hamiltonian", "--width", "8", "--depth", "1", "--epochs", "1", "--quiet"]
    assert main(["train", str(data), "--out", str(tmp_path / "x"), *ham, "--mass-init",
                 "heavy"]) == 2  # fmt: skip
    assert "--mass-init: expected a number or 'data', got 'heavy'" in _error_line(capsys)
    with pytest.raises(SystemExit) as exc:
        main(["train", str(data), "--model", "nonsense", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert "invalid choice" in _error_line(capsys)


def test_progress_bars_count_epochs_then_lbfgs_iterations(capsys):
    """The epoch bar counts AdamW epochs; the L-BFGS finish gets a bar of its own that counts
    its iterations (the epoch bar used to stand still through it)."""
    from softpinn.bridge.cli.bars import EpochBar, TrainBar
    from softpinn.progress import TrainProgress

    def info(phase, epoch, done=None):
        lbfgs = phase == "lbfgs"
        return TrainProgress(done=done if lbfgs else epoch, total=30 if lbfgs else 4,
                             unit="iteration" if lbfgs else "epoch", label="0", phase=phase,
                             epoch=epoch, epochs=4, train_loss=(1e-3,), test_loss=(2e-3,))

    for bar in (TrainBar(4, disable=False), EpochBar()):
        for e in range(1, 5):
            bar(info("adamw", e))
        for done in (10, 20, 30):
            bar(info("lbfgs", 4 + done // 10, done))
        assert bar.lbfgs.bar.n == 30 and bar.lbfgs.bar.total == 30
        assert bar.bar.n == 4
        bar.close()
        assert bar.lbfgs.bar is None
    err = capsys.readouterr().err
    assert "L-BFGS:" in err and "/30 " in err


def test_train_flags_come_from_the_config_fields():
    """One default per setting (issue 14): every TrainConfig setting is a flag of `train` in
    its group, with the field's default and choices, and a change of a field's default shows
    up in the CLI without touching it."""
    import argparse

    from softpinn.bridge.cli import build_parser
    from softpinn.learn._config import GROUPS, TrainConfig
    from softpinn.learn._models import ModelConfig

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    train = sub.choices["train"]
    groups = {g.title: {a.dest: a for a in g._group_actions} for g in train._action_groups}
    for f in TrainConfig.settings():
        group = groups[f.metadata["group"]]
        assert f.name in group, f.name
        action = group[f.name]
        assert action.help, f.name
        if f.name != "test_trajectories":
            assert action.default == f.default, f.name
            assert tuple(action.choices or ()) == tuple(f.metadata.get("choices") or ()), f.name
    assert set(GROUPS) <= set(groups)
    config = TrainConfig(model=ModelConfig(kind="lagrangian", n=2, m=1), lr=3e-3)
    assert config.group("optimizer")["lr"] == 3e-3 and "lr" not in config.group("loss")


def test_network_sizes_of_another_kind_are_refused(data, tmp_path, capsys):
    assert main(["train", str(data), "--model", "blackbox", "--mass", "8", "1", "--out",
                 str(tmp_path / "a")]) == 2
    assert "--mass sizes a physics model's network; a black box's is --hidden" in (
        _error_line(capsys))
    assert main(["train", str(data), "--model", "hamiltonian", "--hidden", "8", "1", "--out",
                 str(tmp_path / "b")]) == 2
    assert "--hidden sizes the black box's network" in _error_line(capsys)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_predict_with_its_arguments_swapped_says_the_order(run, data, capsys):
    assert main(["predict", str(data), str(run), "--horizon", "1"]) == 2
    assert "the order is `softpinn predict RUN DATA.npz`" in _error_line(capsys)


def test_predict_says_which_rollouts_ran_away():
    """A rollout that turns non-finite is named with the time it did, beside the others' mean
    and std (the mean over all is inf, as the paper's tables have it)."""
    from types import SimpleNamespace

    from softpinn.bridge.cli.runnotes import ran_away_text

    t = np.arange(5) * 0.5
    q = np.ones((5, 2))
    bad = q.copy()
    bad[3:] = np.nan
    res = SimpleNamespace(rollout_errors=[0.1, float("inf"), 0.3], trajectories=[4, 7, 9],
                          rollouts=[{"t": t, "q_pred": q}, {"t": t, "q_pred": bad},
                                    {"t": t, "q_pred": q}])
    assert ran_away_text(res) == ("; 1 of 3 ran away (trajectory 7, at t = 1.5 s), the other "
                                   "2: 2.0000e-01 ± 1.000e-01")
    res.rollout_errors = [0.1, 0.2, 0.3]
    assert ran_away_text(res) == ""


def test_an_interrupted_run_says_how_to_go_on(data, tmp_path, capsys):
    """Ctrl-C: the message says how to continue, and predict on the unfinished run says it is
    one (its metrics.json: "interrupted at epoch E")."""
    from types import SimpleNamespace

    from datagen import blackbox_train_config

    from softpinn.bridge.cli._messages import resume_hint as _resume_hint
    from softpinn.learn._train import train

    def stop_at_2(event):
        if event.epoch == 2:
            raise KeyboardInterrupt

    out = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        train(data, blackbox_train_config(epochs=12), out, progress=stop_at_2)
    assert "--resume continues" in _resume_hint(SimpleNamespace(command="train", out=str(out)))
    assert _resume_hint(SimpleNamespace(command="train", out=str(tmp_path / "none"))) == ""
    capsys.readouterr()
    assert main(["predict", str(out), str(data), "--horizon", "1"]) == 0
    err = capsys.readouterr().err
    assert f"the training of {out} was interrupted at epoch 2: its model is the best so far" in err


def test_predict_names_the_member_of_an_ensemble(data, tmp_path, capsys):
    """An ensemble run: predict says which seed it used and how it was chosen."""
    out = tmp_path / "ens"
    flags = [f for f in TRAIN if f != "--quiet"] + ["--quiet", "--seeds", "2", "--epochs", "2"]
    assert main(["train", str(data), "--out", str(out), *flags]) == 0
    capsys.readouterr()
    assert main(["predict", str(out), str(data), "--horizon", "1"]) == 0
    err = capsys.readouterr().err
    assert f"{out} is an ensemble of 2 seeds; this is seed" in err and "the best test loss" in err
    assert main(["predict", str(out), str(data), "--horizon", "1", "--member", "1"]) == 0
    assert "this is seed 1 (given by --member)" in capsys.readouterr().err
