"""The actuator of a run in its export (issue 43 item 2): model.json records it, and the
exported ``actuator_step`` reproduces :meth:`softpinn.actuator.Actuator.apply` (the lag, exact
for commands linear over a step); a run without an actuator exports none."""

from __future__ import annotations

import json

import numpy as np
import pytest
from datagen import make_dataset, tiny_model_config

from softpinn.actuator import Actuator
from softpinn.bridge.export import export_run, load_exported
from softpinn.learn import TrainConfig, train

#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


@pytest.fixture(scope="module")
def run_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("act")
    data = make_dataset(root / "msd.npz", trajectories=3, duration=2.0)
    out = {}
    for name, actuator in (("lag", "0.1:0"), ("none", "none")):
        cfg = TrainConfig(model=tiny_model_config("blackbox"), epochs=2, batch_size=64,
                          lr=1e-2, test_trajectories=(2,), checkpoint_every=1000,
                          actuator=actuator)
        train(data, cfg, root / name)
        out[name] = root / name
    return out


def test_export_records_and_reproduces_the_actuator(run_dirs, tmp_path):
    result = export_run(run_dirs["lag"], tmp_path / "exp")
    meta = json.loads((tmp_path / "exp" / "model.json").read_text())
    m = meta["m"]
    assert meta["actuator"]["text"] == "0.1:0"
    assert meta["actuator"]["time_constant"] == [0.1]
    assert not meta["actuator"]["identity"]
    assert {"actuator", "actuator_step"} <= set(meta["functions"]) == set(result.functions)
    fns = load_exported(tmp_path / "exp")
    act = Actuator.parse("0.1:0", m)
    rng = np.random.default_rng(3)
    t = np.arange(60) * 0.02
    c = rng.normal(size=(60, m))
    want = act.apply(t, c)
    y = c[0].copy()
    got = [y]
    for k in range(59):
        y = np.asarray(fns["actuator_step"](y, c[k], c[k + 1], 0.02)).ravel()
        got.append(y)
    np.testing.assert_allclose(np.array(got), want, rtol=0, atol=1e-12)
    ydot, u = (np.asarray(v).ravel() for v in fns["actuator"](np.ones(m), 3 * np.ones(m)))
    np.testing.assert_allclose(ydot, 20.0)
    np.testing.assert_allclose(u, 1.0)


def test_export_without_actuator(run_dirs, tmp_path):
    export_run(run_dirs["none"], tmp_path / "exp")
    meta = json.loads((tmp_path / "exp" / "model.json").read_text())
    assert meta["actuator"]["identity"] and meta["actuator"]["text"] == "none"
    assert "actuator_step" not in meta["functions"]
    assert "actuator" not in load_exported(tmp_path / "exp")
