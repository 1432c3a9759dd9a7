"""Validation trajectories (issue 43, "model selection on the test set"): held out of training,
their loss picks the best epoch and decides patience; the test loss is only recorded. The
default rule, the flag, its one-line errors, and the resume of a run from before the change."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
from datagen import blackbox_train_config, make_dataset, write

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._data import load_dataset, make_pairs
from softpinn.learn._splits import NO_VALIDATION_NOTE, validation_split
from softpinn.learn._train import train

train_module = importlib.import_module("softpinn.learn._train")  # the module, not train()
programs_module = importlib.import_module("softpinn.learn._programs")

TRAIN = [
    "--model", "blackbox", "--hidden", "16", "2", "--epochs", "3", "--batch-size", "64",
    "--lr", "1e-2", "--test-trajectories", "4", "--checkpoint-every", "1000", "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("val") / "msd.npz", trajectories=5, duration=4.0)


def _pairs(data, ids):
    return make_pairs(load_dataset(data), np.asarray(ids), state="velocity").count


def test_validation_trajectories_are_held_out_of_the_training_pairs(data, tmp_path):
    res = train(data, blackbox_train_config(epochs=2, validation=(0, 1)), tmp_path / "run")
    info = ckpt.read_json(tmp_path / "run" / "config.json")
    assert info["split"] == {"train": [2, 3], "validation": [0, 1], "test": [4]}
    assert info["pairs"]["train"] == _pairs(data, [2, 3])
    assert info["pairs"]["validation"] == _pairs(data, [0, 1])
    assert info["pairs"]["test"] == _pairs(data, [4])
    rows = ckpt.read_history(tmp_path / "run" / "history.csv")
    assert all("validation_loss" in r for r in rows)
    m = res.members[0].metrics
    assert m["train_pairs"] == _pairs(data, [2, 3]) and "best_validation_loss" in m


def test_default_rule(data):
    ds = load_dataset(data)
    four = np.arange(4)
    # simulated file: the library holds out none; auto: 20% of 4 -> 1, drawn with the seed
    assert validation_split(ds, four, None)[1].tolist() == []
    tr, va, note = validation_split(ds, four, "auto", seed=3)
    assert va.size == 1 and sorted(tr.tolist() + va.tolist()) == [0, 1, 2, 3] and note is None
    assert validation_split(ds, four, "auto", seed=3)[1].tolist() == va.tolist()
    # fewer than 3 training trajectories: none, and one note says the test loss picks
    assert validation_split(ds, np.arange(2), "auto") == (
        pytest.approx(np.arange(2)), pytest.approx(np.zeros(0)), NO_VALIDATION_NOTE)
    # an imported recording: None is the rule
    imported = load_dataset(data)
    imported.meta["source"] = "import"
    assert validation_split(imported, four, None)[1].size == 1
    assert validation_split(ds, np.arange(10), 0.3)[1].size == 3
    assert validation_split(ds, four, 0)[1].size == 0


def test_best_epoch_follows_the_validation_loss_not_the_test_loss(data, tmp_path,
                                                                  monkeypatch):
    """The validation loss is lowest at epoch 2 and the test loss at the last epoch: the kept
    epoch, patience and the recorded best follow validation; test is only recorded."""
    val = iter([5.0, 4.0, 1.0, 3.0, 6.0, 7.0, 8.0, 9.0])
    test = iter([5.0, 4.0, 3.0, 2.0, 1.0, 0.5, 0.25, 0.1])
    monkeypatch.setattr(programs_module.Programs, "eval_fn",
                        lambda self, params: np.array([next(val)]))
    monkeypatch.setattr(train_module, "_test_evaluator",
                        lambda prog, pairs, count: lambda params: np.array([next(test)]))
    res = train(data, blackbox_train_config(epochs=7, validation=(0,), patience=2),
                tmp_path / "run")
    m = res.members[0].metrics
    assert m["best_epoch"] == 2 and m["best_validation_loss"] == 1.0
    assert m["best_test_loss"] == 3.0  # the kept model's test loss, not the lowest one
    assert m["stop_reason"] == "patience" and m["epochs_run"] == 4
    rows = ckpt.read_history(tmp_path / "run" / "history.csv")
    assert [r["validation_loss"] for r in rows] == [5.0, 4.0, 1.0, 3.0, 6.0]
    assert [r["test_loss"] for r in rows] == [5.0, 4.0, 3.0, 2.0, 1.0]
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["best_epoch"] == 2


def test_resume_of_a_run_without_validation_goes_on_as_before(data, tmp_path, monkeypatch):
    """A run from before issue 43 (no "validation" in its split or settings) resumes with the
    test loss picking, and gives the same numbers as a run of today without validation."""
    train(data, blackbox_train_config(epochs=3, validation=0), tmp_path / "new")
    whole = train(data, blackbox_train_config(epochs=6, validation=0), tmp_path / "new",
                  resume=True)
    out = tmp_path / "old"
    train(data, blackbox_train_config(epochs=3, validation=0), out)
    info = ckpt.read_json(out / "config.json")
    del info["split"]["validation"], info["train"]["validation"]
    ckpt.atomic_write_json(out / "config.json", info, record=True)

    def no_new_split(*args, **kwargs):
        raise AssertionError("the validation split was drawn on resume")

    monkeypatch.setattr(train_module, "validation_split", no_new_split)
    res = train(data, blackbox_train_config(epochs=6), out, resume=True)
    m, ref = res.members[0].metrics, whole.members[0].metrics
    assert "best_validation_loss" not in m
    assert m["best_test_loss"] == ref["best_test_loss"] and m["best_epoch"] == ref["best_epoch"]
    assert "validation" not in ckpt.read_json(out / "config.json")["split"]


def test_cli_holds_out_validation_on_imported_recordings_and_says_so(data, tmp_path, capsys):
    """The default: the rule on a file of softpinn import, none on a simulated one (as
    before); --validation auto asks for the rule anywhere, 0 for none."""
    arrays = dict(np.load(data))
    meta = json.loads(str(arrays.pop("meta")))
    imported = write(tmp_path / "imported.npz", arrays, {**meta, "source": "import"})
    assert main(["train", str(imported), "--out", str(tmp_path / "a"), *TRAIN]) == 0
    out = capsys.readouterr().out
    info = json.loads((tmp_path / "a" / "config.json").read_text())
    assert len(info["split"]["validation"]) == 1 and info["split"]["test"] == [4]
    assert f"validation: trajectory {info['split']['validation'][0]} (they pick" in out
    assert main(["train", str(data), "--out", str(tmp_path / "s"), *TRAIN]) == 0
    assert "validation: none; the test loss picks" in capsys.readouterr().out
    assert json.loads((tmp_path / "s" / "config.json").read_text())["split"]["validation"] == []
    assert main(["train", str(data), "--out", str(tmp_path / "u"), *TRAIN,
                 "--validation", "auto"]) == 0
    assert json.loads((tmp_path / "u" / "config.json").read_text())["split"] == {
        "train": info["split"]["train"],
        "validation": info["split"]["validation"], "test": [4]}  # the same seeded draw
    assert main(["train", str(imported), "--out", str(tmp_path / "b"), *TRAIN,
                 "--validation", "0"]) == 0
    assert "validation: none; the test loss picks" in capsys.readouterr().out
    # too few training trajectories for the rule: none, with the note
    flags = [f for f in TRAIN if f not in ("--test-trajectories", "4")]
    assert main(["train", str(imported), "--out", str(tmp_path / "c"), *flags,
                 "--test-trajectories", "2", "3", "4"]) == 0
    assert NO_VALIDATION_NOTE in capsys.readouterr().out
    assert json.loads((tmp_path / "c" / "config.json").read_text())["notes"] == [
        NO_VALIDATION_NOTE]


@pytest.mark.parametrize("value, words", [
    ("4,", "--validation: trajectories [4] are not training trajectories"),
    ("4", "--validation: 4 validation trajectories leave none"),
])  # fmt: skip
def test_cli_bad_values_are_one_line_naming_the_flag(data, tmp_path, capsys, value, words):
    capsys.readouterr()
    assert main(["train", str(data), "--out", str(tmp_path / "r"), *TRAIN,
                 "--validation", value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not (tmp_path / "r" / "config.json").exists()


@pytest.mark.parametrize("value", ["x", "1.5", "-1"])
def test_cli_unreadable_values_name_the_flag(data, tmp_path, capsys, value):
    with pytest.raises(SystemExit):
        main(["train", str(data), "--out", str(tmp_path / "r"), *TRAIN, "--validation", value])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--validation" in err[0], err


def test_library_bad_values_name_the_flag(data, tmp_path):
    with pytest.raises(UserError, match="--validation"):
        blackbox_train_config(validation="most")
    with pytest.raises(UserError, match="--validation: trajectories \\[4\\]"):
        train(data, blackbox_train_config(validation=(4,)), tmp_path / "r")


def test_a_single_trajectory_file_notes_the_test_pick(data, tmp_path):
    arrays = dict(np.load(data))
    arrays.pop("meta")
    one = {k: v[arrays["traj"] == 0] for k, v in arrays.items()}
    single = write(tmp_path / "one.npz", one, {"spec": {"name": "one"}, "source": "import"})
    train(single, blackbox_train_config(epochs=1, test_trajectories=None), tmp_path / "r")
    info = ckpt.read_json(tmp_path / "r" / "config.json")
    assert info["notes"] == [NO_VALIDATION_NOTE] and info["split"]["validation"] == []
