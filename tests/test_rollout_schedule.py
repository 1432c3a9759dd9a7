"""Issue 43, multi-step training: ``rollout_schedule`` (horizons from one step to the one a user
needs, stages spread evenly over the AdamW epochs), each stage compiled once, the held-out loss
always at the last horizon, and the fraction of training windows whose rollout leaves the
training data's range recorded, never silent."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from datagen import make_dataset, tiny_model_config

from softpinn.errors import UserError
from softpinn.learn._config import TrainConfig
from softpinn.learn._data import load_dataset, make_windows
from softpinn.learn._losses import rollout_errors
from softpinn.learn._models import make_model
from softpinn.learn._objective import errors_function, rollout_stage, to_windows, training_box
from softpinn.learn._programs import ProgramCache
from softpinn.learn._train import train


def _cfg(**kw):
    base = dict(model=tiny_model_config("blackbox"), epochs=6, batch_size=64, lr=1e-2,
                test_trajectories=(4,), checkpoint_every=1000, loss="rollout")
    base.update(kw)
    return TrainConfig(**base)


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    # five 3 s trajectories at 20 Hz (61 samples, 60 steps each): the linear two-mass system
    return make_dataset(tmp_path_factory.mktemp("rs") / "msd.npz", trajectories=5,
                        duration=3.0, rate=20.0)


def test_stages_spread_evenly_over_the_epochs():
    cfg = _cfg(epochs=10, rollout_schedule=(1, 4, 16))
    assert cfg.rollout_steps == 16  # the windows' length is the last horizon
    # stage i from epoch ceil(i * 10 / 3) + 1: epochs 1-4, 5-7, 8-10
    assert [rollout_stage(cfg, e) for e in range(1, 11)] == [1] * 4 + [4] * 3 + [16] * 3
    cfg = _cfg(epochs=8, rollout_schedule=(1, 2, 4, 8))
    assert [rollout_stage(cfg, e) for e in range(1, 9)] == [1, 1, 2, 2, 4, 4, 8, 8]
    assert rollout_stage(_cfg(rollout_steps=3), 5) == 3  # no schedule: one horizon throughout
    # beyond the configured epochs (L-BFGS, a resumed run's extra epochs): the last stage
    assert rollout_stage(cfg, 20) == 8


@pytest.mark.parametrize(("kw", "match"), [
    (dict(rollout_schedule=(1, 4), loss="pair"), r"rollout_schedule \(--rollout-schedule\): "
     r"a schedule of horizons is for loss 'rollout'"),
    (dict(rollout_schedule=(4, 2)), "the horizons must increase, got 4,2"),
    (dict(rollout_schedule=(2, 2)), "the horizons must increase"),
    (dict(rollout_schedule=(0, 2)), "integers >= 1"),
    (dict(rollout_schedule=(1, 2.5)), "integers >= 1"),
    (dict(rollout_schedule=()), "integers >= 1"),
    (dict(rollout_schedule=(1, 8), rollout_steps=4), "its last horizon \\(8\\) is the rollout's "
     "length; leave out --rollout-steps \\(4\\) or give 8"),
])
def test_refusals_name_the_flag(kw, match):
    with pytest.raises(UserError, match=match):
        _cfg(**kw)


def test_refused_when_longer_than_the_shortest_training_trajectory(msd, tmp_path):
    with pytest.raises(UserError, match=r"--rollout-schedule\): the last horizon \(61 steps\) "
                       r"is longer than the shortest training trajectory \(60 steps\)"):
        train(msd, _cfg(rollout_schedule=(1, 61)), tmp_path / "run")


def test_cli_parses_the_schedule():
    from softpinn.bridge.cli import build_parser

    args = build_parser().parse_args(["train", "d.npz", "--model", "blackbox", "--out", "r",
                                      "--loss", "rollout", "--rollout-schedule", "1,4,16"])
    assert args.rollout_schedule == (1, 4, 16)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train", "d.npz", "--rollout-schedule", "1,x"])


def test_schedule_trains_each_stage_compiled_once(msd, tmp_path):
    cfg = _cfg(epochs=6, rollout_schedule=(1, 2, 4))
    cache = ProgramCache()
    res = train(msd, cfg, tmp_path / "run", programs=cache)
    (prog,) = cache.entries.values()
    # one program per horizon, each compiled exactly once over the 6 epochs
    assert {h: f._cache_size() for h, f in prog._epoch_fns.items()} == {1: 1, 2: 1, 4: 1}
    hist = res.members[0].history
    assert [r.get("horizon") for r in hist] == [None, 1, 1, 2, 2, 4, 4]
    assert all(0.0 <= r["out_of_range"] <= 1.0 for r in hist[1:])
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert "rollout_out_of_range" in json.dumps(metrics)
    # a second run of the same configuration compiles nothing new
    train(msd, cfg, tmp_path / "again", programs=cache)
    assert {h: f._cache_size() for h, f in prog._epoch_fns.items()} == {1: 1, 2: 1, 4: 1}


def test_held_out_loss_is_at_the_last_horizon(msd):
    cfg = _cfg(rollout_schedule=(1, 2, 4))
    data = load_dataset(msd)
    win = to_windows(make_windows(data, [4], horizon=4), jnp.float64)
    model = make_model(cfg.model, key=jax.random.PRNGKey(0))
    np.testing.assert_allclose(errors_function(cfg, test=True)(model, win),
                               rollout_errors(model, win, horizon=4), rtol=1e-12)


def test_training_box_widens_by_half_the_width():
    x = jnp.array([[[0.0, 10.0, 0.0, 0.0], [2.0, 10.0, 5.0, 5.0]]])  # q0 in [0, 2], q1 = 10
    low, high = training_box(x, 2)
    np.testing.assert_allclose(low[0], -1.0)
    np.testing.assert_allclose(high[0], 3.0)
    assert float(low[1]) < 10.0 < float(high[1])  # a constant coordinate gets a tiny margin


def test_schedule_beats_one_step_training_over_five_steps(msd, tmp_path):
    """A schedule 1, 2, 5 against the pair loss at the same budget (epochs, windows as many as
    pairs): its 5-step rollout error on the held-out trajectory is not worse."""
    data = load_dataset(msd)
    test = to_windows(make_windows(data, [4], horizon=5), jnp.float64)
    errors = {}
    for name, kw in (("pair", dict(loss="pair")), ("schedule", dict(rollout_schedule=(1, 2, 5)))):
        res = train(msd, _cfg(epochs=30, samples=200, **kw), tmp_path / name)
        errors[name] = float(jnp.mean(rollout_errors(res.model, test, horizon=5)))
    assert errors["schedule"] <= errors["pair"], errors
