"""Settings clearly off for the data are told before training (learn/_advice.py): too few
optimizer steps per epoch, an initial mass diagonal orders of magnitude from the data's."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from datagen import make_dataset, simulate, tiny_model_config, write

from softpinn.bridge.cli import main
from softpinn.learn._advice import setting_warnings
from softpinn.learn._config import TrainConfig
from softpinn.learn._data import load_dataset, mass_scale
from softpinn.learn._known_input import known_input_text


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return load_dataset(make_dataset(tmp_path_factory.mktemp("adv") / "msd.npz",
                                     trajectories=5, duration=4.0))


def _cfg(**kw):
    net = {k: kw.pop(k) for k in ("mass_init", "input_form", "known_input") if k in kw}
    return TrainConfig(model=tiny_model_config(kw.pop("kind", "lagrangian"), **net), **kw)


def test_few_steps_per_epoch_warns_naming_the_field(data):
    (msg,) = setting_warnings(_cfg(batch_size=1024), data, 300, 300)
    assert msg.startswith("batch_size: 300 on 300 training pairs makes 1 optimizer step(s)")
    # the default batch (at least 64) is not blamed for small data; enough steps: no warning
    assert setting_warnings(_cfg(), data, 300, 64) == []
    assert setting_warnings(_cfg(batch_size=128), data, 20 * 128, 128) == []


def test_mass_far_from_the_data_warns(tmp_path, data):
    assert setting_warnings(_cfg(), data, 1000, 64) == []  # the msd's masses are near 1
    arrays = simulate("msd", trajectories=3, duration=2.0)
    arrays["p"] = arrays["p"] * 1e3  # masses ~1000 times larger
    heavy = load_dataset(write(tmp_path / "heavy.npz", arrays))
    known = {"input_form": "known", "known_input": known_input_text(np.array([[0.0], [1.0]]))}
    (msg,) = setting_warnings(_cfg(**known), heavy, 1000, 64)
    assert msg.startswith("mass_init: the network's M starts near 1 on its diagonal")
    (msg,) = setting_warnings(_cfg(kind="hamiltonian"), heavy, 1000, 64)
    assert "M⁻¹ starts near 1" in msg
    scale = mass_scale(heavy, "lagrangian")
    assert setting_warnings(_cfg(mass_init=scale, **known), heavy, 1000, 64) == []
    # with A learned, M's scale is a gauge the data do not fix: moving M alone would only
    # make the first q̈ that many times off, so it is not advised
    assert setting_warnings(_cfg(), heavy, 1000, 64) == []
    # a network started from an earlier run's model does not start at mass_init: no advice
    assert setting_warnings(_cfg(init=str(tmp_path)), heavy, 1000, 64) == []


def test_train_logs_and_the_cli_prints_the_flag(data, tmp_path, capsys, caplog):
    from softpinn.learn._train import train

    cfg = TrainConfig(model=tiny_model_config("blackbox"), epochs=1, batch_size=300,
                      test_trajectories=(4,))
    with caplog.at_level(logging.WARNING, logger="softpinn.learn"):
        train(data, cfg, tmp_path / "a")
    assert any(r.getMessage().startswith("batch_size: ") for r in caplog.records)
    assert main(["train", str(data.path), "--model", "blackbox", "--hidden", "16", "2",
                 "--epochs", "1", "--batch-size", "300", "--test-trajectories", "4",
                 "--out", str(tmp_path / "b"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("softpinn: warning: --batch-size: ")
