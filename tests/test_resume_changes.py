"""Resume with changed settings (issue 15): the settings that may change on resume (epochs,
patience, L-BFGS steps, ...) are honoured, any other change is refused with one line that
lists what differs; the run's config.json records what it continued with."""

from __future__ import annotations

import pytest
from datagen import blackbox_train_config, make_dataset

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._train import train

TRAIN = [
    "--model", "blackbox", "--hidden", "16", "2", "--batch-size", "64", "--lr", "1e-2",
    "--test-trajectories", "4", "--checkpoint-every", "1000", "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("res") / "msd.npz", trajectories=5, duration=4.0)


def _epochs(run):
    return [r["epoch"] for r in ckpt.read_history(run / "history.csv")]


def test_resume_with_more_epochs_trains_to_them(data, tmp_path):
    out = tmp_path / "run"
    train(data, blackbox_train_config(epochs=5), out)
    assert _epochs(out) == list(range(6))
    res = train(data, blackbox_train_config(epochs=50), out, resume=True)
    assert _epochs(out) == list(range(51))
    m = res.members[0].metrics
    assert m["epochs_run"] == 50 and m["stopped"] == "completed 50 epochs"
    assert ckpt.read_json(out / "config.json")["train"]["epochs"] == 50
    # resuming again without a config continues the stored 50-epoch run: nothing to do
    again = train(data, None, out, resume=True)
    assert again.members[0].metrics["epochs_run"] == 50


def test_cli_resume_epochs_50_after_5(data, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["train", str(data), "--out", str(out), *TRAIN, "--epochs", "5"]) == 0
    assert main(["train", str(data), "--out", str(out), "--resume", "--epochs", "50",
                 "--quiet"]) == 0
    assert _epochs(out) == list(range(51))
    # options not typed again keep their stored values (the default --epochs is not applied)
    assert main(["train", str(data), "--out", str(out), "--resume", "--quiet"]) == 0
    assert ckpt.read_json(out / "config.json")["train"]["epochs"] == 50
    capsys.readouterr()
    # another --model: said so, not as a list of network sizes nobody typed
    assert main(["train", str(data), "--out", str(out), "--model", "lagrangian", "--resume",
                 "--quiet"]) == 2
    assert "the run holds a blackbox model; --model lagrangian cannot continue it" in (
        capsys.readouterr().err)
    # the run's own --model typed again (the help says it is required) changes nothing
    assert main(["train", str(data), "--out", str(out), "--model", "blackbox", "--resume",
                 "--quiet"]) == 0
    # the same command again with --resume is accepted
    assert main(["train", str(data), "--out", str(out), *TRAIN, "--epochs", "50",
                 "--resume"]) == 0


def test_resume_refuses_other_changes_naming_them(data, tmp_path, capsys):
    out = tmp_path / "run"
    train(data, blackbox_train_config(epochs=3), out)
    with pytest.raises(UserError, match=r"batch_size \(run: 64, given: 32\); lr \(run: 0.01, "
                                        r"given: 0.5\) \(only epochs, patience"):
        train(data, blackbox_train_config(epochs=3, lr=0.5, batch_size=32), out, resume=True)
    before = (out / "config.json").read_bytes()
    assert main(["train", str(data), "--out", str(out), "--resume", "--lr", "0.5",
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lr (run: 0.01, given: 0.5)" in err[0]
    assert main(["train", str(data), "--out", str(out), "--resume", "--hidden", "8", "2",
                 "--quiet"]) == 2
    assert "model.hidden (run: (16, 2), given: (8, 2))" in capsys.readouterr().err
    assert (out / "config.json").read_bytes() == before  # a refused resume changes nothing


def test_more_epochs_after_lbfgs_are_refused(data, tmp_path):
    out = tmp_path / "run"
    train(data, blackbox_train_config(epochs=2, lbfgs_steps=10), out)
    with pytest.raises(UserError, match="ended with 10 L-BFGS iterations after 2 epochs"):
        train(data, blackbox_train_config(epochs=4, lbfgs_steps=10), out, resume=True)
    assert ckpt.read_json(out / "config.json")["train"]["epochs"] == 2


def test_resume_keeps_the_split_the_run_recorded(data, tmp_path, monkeypatch):
    """A resumed run goes on with the trajectories its config.json records as its split; it
    does not draw them again (a default that changed since must not move them)."""
    import importlib

    train_module = importlib.import_module("softpinn.learn._train")  # the module, not train()

    out = tmp_path / "run"
    train(data, blackbox_train_config(epochs=3), out)
    recorded = ckpt.read_json(out / "config.json")["split"]

    def no_new_split(*args, **kwargs):
        raise AssertionError("the split was drawn again on resume")

    monkeypatch.setattr(train_module, "split_trajectories", no_new_split)
    res = train(data, blackbox_train_config(epochs=6), out, resume=True)
    assert ckpt.read_json(out / "config.json")["split"] == recorded
    assert res.members[0].metrics["epochs_run"] == 6
