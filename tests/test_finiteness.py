"""Finiteness (issue 15): NaN and inf are refused where they enter (every numeric setting,
every loaded array, every loaded model), a model whose loss is not finite from the start is a
failure that leaves nothing behind, and no JSON file softpinn writes holds NaN or Infinity."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import pytest
from datagen import blackbox_train_config, make_dataset, simulate, write

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._models import ModelConfig
from softpinn.learn._rundir import load_run
from softpinn.learn._train import TrainingDiverged, train

NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("fin") / "msd.npz", trajectories=5, duration=4.0)


@pytest.mark.parametrize("field", ["lr", "warmup", "lr_final", "weight_decay", "clip_norm",
                                   "loss_weight"])
@pytest.mark.parametrize("value", [NAN, INF, -INF])
def test_every_float_setting_refuses_nan_and_inf(field, value):
    with pytest.raises(UserError, match=f"^{field}: expected"):
        blackbox_train_config(**{field: value})


@pytest.mark.parametrize("value", [NAN, INF])
def test_model_settings_refuse_nan_and_inf(value):
    with pytest.raises(UserError, match="eps: must be a finite number >= 0"):
        ModelConfig(kind="lagrangian", n=2, m=1, eps=value)
    with pytest.raises(UserError, match="mass_init: must be a number > 0"):
        ModelConfig(kind="lagrangian", n=2, m=1, mass_init=value)


def test_seeds_must_fit_32_bits():
    with pytest.raises(UserError, match=r"seed: expected an integer <= 4294967295"):
        blackbox_train_config(seed=99999999999999999999)
    with pytest.raises(UserError, match=r"seed: expected an integer <= 4294967294"):
        blackbox_train_config(seed=2**32 - 1, seeds=2)
    with pytest.raises(UserError, match=r"split_seed: expected an integer <= 4294967295"):
        blackbox_train_config(split_seed=2**40)


def test_cli_huge_seed_is_one_line_and_leaves_nothing(data, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", str(data), "--model", "blackbox", "--out", str(out), "--quiet"]
    assert main([*args, "--seed", "99999999999999999999"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["softpinn: error: --seed: expected an integer <= 4294967295 (seeds are "
                   "32-bit), got 99999999999999999999"]
    assert not out.exists()


def test_dataset_with_non_finite_values_is_refused(tmp_path):
    from softpinn.learn._data import load_dataset

    arrays = simulate("msd", trajectories=2, duration=1.0)
    arrays["qd"][3, 1] = INF
    with pytest.raises(UserError, match="qd"):
        load_dataset(write(tmp_path / "inf.npz", arrays))


def test_model_non_finite_from_the_start_fails_and_leaves_nothing(tmp_path, capsys):
    arrays = simulate("msd", trajectories=5, duration=4.0)
    for key in ("q", "qd", "qdd"):
        arrays[key] = arrays[key] * 1e200  # finite, but the loss overflows
    path = write(tmp_path / "huge.npz", arrays)
    out = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match="untrained model's loss is not finite"):
        train(path, blackbox_train_config(), out)
    assert list(out.iterdir()) == []  # a rerun is not blocked
    assert main(["train", str(path), "--model", "blackbox", "--out", str(out), "--quiet",
                 "--hidden", "16", "2", "--epochs", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "untrained model's loss is not finite" in err[0]


def test_json_files_never_hold_nan(tmp_path):
    ckpt.atomic_write_json(tmp_path / "m.json", {"a": NAN, "b": [1.0, INF], "c": {"d": -INF}})
    text = (tmp_path / "m.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [1.0, None], "c": {"d": None}}


def test_load_run_refuses_non_finite_parameters(data, tmp_path):
    import equinox as eqx

    train(data, blackbox_train_config(), tmp_path / "run")
    run = load_run(tmp_path / "run")
    params = eqx.filter(run.model, eqx.is_array)
    leaves, tree = jax.tree.flatten(params)
    leaves[0] = jnp.full_like(leaves[0], jnp.nan)
    ckpt.save_tree(tmp_path / "run" / "model.eqx", jax.tree.unflatten(tree, leaves), {"seed": 0})
    with pytest.raises(UserError, match="model.eqx: the model's parameters are not all finite"):
        load_run(tmp_path / "run")

