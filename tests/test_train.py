"""Training (learn/_train.py): physics nets learn the analytic systems, ensembles equal single
runs, resume equals an uninterrupted run, interruption and divergence leave loadable runs."""

from __future__ import annotations

import dataclasses
import os
import signal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from datagen import blackbox_train_config, make_dataset, tiny_model_config

from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._data import load_dataset
from softpinn.learn._models import make_model
from softpinn.learn._predict import evaluate
from softpinn.learn._programs import PROGRAMS
from softpinn.learn._train import (
    TrainConfig,
    TrainingDiverged,
    load_ensemble,
    load_run,
    train,
)


def _leaves(model):
    return jax.tree.leaves(eqx.filter(model, eqx.is_array))


def assert_same_params(a, b, *, exact=False):
    la, lb = _leaves(a), _leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb, strict=True):
        if exact:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        else:
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-9, atol=1e-12)


@pytest.fixture(scope="module")
def msd(tmp_path_factory):
    path = make_dataset(tmp_path_factory.mktemp("msd") / "msd.npz", trajectories=5, duration=4.0)
    return load_dataset(path)


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory):
    path = make_dataset(
        tmp_path_factory.mktemp("pend") / "pend.npz", "pendulum", trajectories=4, duration=3.0
    )
    return load_dataset(path)


def _learns(data, config, out, horizon):
    """Train; return (initial test loss, best test loss, trained rollout, untrained rollout)."""
    res = train(data, config, out)
    hist = res.members[0].history
    assert hist[0]["epoch"] == 0  # the untrained model is recorded first
    ids = list(config.test_trajectories)
    trained = evaluate(res.model, data, ids, horizon=horizon)
    untrained = evaluate(
        make_model(config.model, key=jax.random.PRNGKey(0)), data, ids, horizon=horizon
    )
    return hist[0]["test_loss"], res.metrics["best_test_loss"]["mean"], trained, untrained


def test_lagrangian_learns_mass_spring_damper(msd, tmp_path):
    cfg = TrainConfig(
        model=tiny_model_config("lagrangian"),
        epochs=150,
        batch_size=32,
        lr=1e-2,
        test_trajectories=(4,),
    )
    first, best, trained, untrained = _learns(msd, cfg, tmp_path / "lag", horizon=2.7)
    assert best < first / 100, (first, best)
    assert trained.one_step_error["mean"] < untrained.one_step_error["mean"] / 100
    assert trained.rollout_error_mean < untrained.rollout_error_mean / 100, (
        trained.rollout_error_mean,
        untrained.rollout_error_mean,
    )
    run = load_run(tmp_path / "lag")
    # the stored config is the one given, its actuator resolved (simulated data: none)
    assert run.model_config == cfg.model
    assert run.train_config == dataclasses.replace(cfg, actuator="none")
    mats = run.model.matrices(jnp.zeros(2))
    assert mats["M"].shape == (2, 2) and mats["A"].shape == (2, 1)


def test_hamiltonian_learns_pendulum(pendulum, tmp_path):
    cfg = TrainConfig(
        model=tiny_model_config("hamiltonian", n=1, m=1),
        epochs=100,
        batch_size=32,
        lr=2e-2,
        test_trajectories=(3,),
    )
    first, best, trained, untrained = _learns(pendulum, cfg, tmp_path / "ham", horizon=2.0)
    assert best < first / 100, (first, best)
    assert trained.rollout_error_mean < untrained.rollout_error_mean / 100


def test_ensemble_members_equal_single_runs(msd, tmp_path):
    cfg = blackbox_train_config(seeds=2, seed=3)
    vm = train(msd, dataclasses.replace(cfg, ensemble="vmap"), tmp_path / "vmap")
    sq = train(msd, dataclasses.replace(cfg, ensemble="sequential"), tmp_path / "seq")
    singles = [
        train(msd, dataclasses.replace(cfg, seeds=1, seed=s), tmp_path / f"single{s}")
        for s in (3, 4)
    ]
    assert [m.seed for m in vm.members] == [3, 4]
    for k in range(2):
        assert_same_params(vm.members[k].model, singles[k].members[0].model)
        assert_same_params(sq.members[k].model, singles[k].members[0].model, exact=True)
        np.testing.assert_allclose(
            vm.members[k].metrics["best_test_loss"],
            singles[k].metrics["best_test_loss"]["mean"],
            rtol=1e-9,
        )
    # different seeds give different models, and the aggregate is their mean and std
    assert not np.allclose(_leaves(vm.members[0].model)[0], _leaves(vm.members[1].model)[0])
    best = [m.metrics["best_test_loss"] for m in vm.members]
    assert vm.metrics["best_test_loss"]["mean"] == pytest.approx(np.mean(best))
    assert vm.metrics["best_test_loss"]["std"] == pytest.approx(np.std(best))
    members = load_ensemble(tmp_path / "vmap")
    assert [r.seed for r in members] == [3, 4]
    assert load_run(tmp_path / "vmap").seed == vm.metrics["best_member"]
    assert_same_params(load_run(tmp_path / "vmap", member=4).model, vm.members[1].model, exact=True)
    # a member folder is not resumed on its own (it would start a new ensemble inside it)
    before = sorted(p.name for p in (tmp_path / "vmap" / "seed-3").iterdir())
    msg = r"seed-3 holds one member \(seed 3\) of a 2-member ensemble; resume the ensemble's"
    with pytest.raises(UserError, match=msg + r" directory \(.*vmap if"):
        train(msd, None, tmp_path / "vmap" / "seed-3", resume=True)
    assert sorted(p.name for p in (tmp_path / "vmap" / "seed-3").iterdir()) == before


class _StopAt:
    def __init__(self, epoch):
        self.epoch = epoch

    def __call__(self, event):
        if event.epoch == self.epoch:
            raise KeyboardInterrupt


def test_interrupt_then_resume_equals_uninterrupted(msd, tmp_path):
    cfg = blackbox_train_config()
    full = train(msd, cfg, tmp_path / "full")
    with pytest.raises(KeyboardInterrupt):
        train(msd, cfg, tmp_path / "part", progress=_StopAt(5))
    # the interrupted run is loadable, and its checkpoint holds the 5 completed epochs
    header = ckpt.read_header(tmp_path / "part" / "checkpoint.eqx")
    assert header["epoch"] == 5 and not header["adam_done"]
    assert [r["epoch"] for r in ckpt.read_history(tmp_path / "part" / "history.csv")] == list(
        range(6)
    )
    assert load_run(tmp_path / "part").seed == 0
    assert ckpt.read_json(tmp_path / "part" / "metrics.json")["stopped"] == (
        "interrupted at epoch 5 (--resume continues)")
    resumed = train(msd, None, tmp_path / "part", resume=True)
    assert resumed.members[0].metrics["stopped"].startswith("completed")
    assert_same_params(resumed.model, full.model, exact=True)
    strip = lambda h: [(r["epoch"], r["train_loss"], r["test_loss"]) for r in h]
    assert strip(resumed.members[0].history) == strip(full.members[0].history)
    # model.eqx round trip gives the same parameters
    assert_same_params(load_run(tmp_path / "part").model, full.model, exact=True)
    # resuming with options that make another run is refused (more epochs are honoured:
    # tests/test_resume_changes.py)
    with pytest.raises(UserError, match=r"resume: .* cannot change on resume: lr \(run: 0.01, "
                                        r"given: 0.02\)"):
        train(msd, dataclasses.replace(cfg, lr=0.02), tmp_path / "part", resume=True)


def test_ctrl_c_finishes_the_epoch_then_saves(msd, tmp_path, ctrl_c_raises):
    cfg = blackbox_train_config()

    def sigint_at_3(event):
        if event.epoch == 3:
            os.kill(os.getpid(), signal.SIGINT)  # like Ctrl-C while epoch 3 is reported

    with pytest.raises(KeyboardInterrupt):
        train(msd, cfg, tmp_path / "c", progress=sigint_at_3)
    assert ckpt.read_header(tmp_path / "c" / "checkpoint.eqx")["epoch"] == 3
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored
    resumed = train(msd, None, tmp_path / "c", resume=True)
    full = train(msd, cfg, tmp_path / "full")
    assert_same_params(resumed.model, full.model, exact=True)


def test_existing_run_dir_needs_force(msd, tmp_path):
    cfg = blackbox_train_config(epochs=12)
    train(msd, cfg, tmp_path / "first")
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    with pytest.raises(UserError, match="already exists and is not empty; use --force"):
        train(msd, cfg, out)
    before = {id(p): p._epoch_fn._cache_size() for p in PROGRAMS.entries.values()}
    train(msd, cfg, out, force=True)
    # a second run of an already-compiled configuration traces nothing new
    after = {id(p): p._epoch_fn._cache_size() for p in PROGRAMS.entries.values()}
    assert before == after and len(before) >= 1
    assert (out / "notes.txt").read_text() == "keep me"
    assert (out / "model.eqx").is_file() and (out / "loss.png").is_file()
    rows = ckpt.read_history(out / "history.csv")
    assert [r["epoch"] for r in rows] == list(range(13))


# the NaN and early-stopping tests share one float32 program (the learning rate is not compiled)
F32 = dict(model=tiny_model_config("blackbox", dtype="float32"), schedule="constant", warmup=0.0)


def test_nan_loss_stops_with_message(msd, tmp_path):
    cfg = blackbox_train_config(lr=1e30, **F32)
    with pytest.raises(TrainingDiverged, match=r"loss became NaN/inf \(seed 0: diverged at epoch"):
        train(msd, cfg, tmp_path / "nan")
    run = load_run(tmp_path / "nan")
    assert all(np.isfinite(np.asarray(x)).all() for x in _leaves(run.model))
    header = ckpt.read_header(tmp_path / "nan" / "checkpoint.eqx")
    assert header["stopped"][0].startswith("diverged")


def test_early_stopping_keeps_best(msd, tmp_path):
    cfg = blackbox_train_config(epochs=12, lr=0.3, patience=2, **F32)
    res = train(msd, cfg, tmp_path / "es")
    assert all(x.dtype == jnp.float32 for x in _leaves(res.model))
    m = res.members[0].metrics
    assert m["stopped"].startswith("early stop") and m["epochs_run"] < 12
    hist = res.members[0].history
    assert m["best_test_loss"] == min(r["test_loss"] for r in hist)
    assert hist[-1]["epoch"] - m["best_epoch"] == 2


def test_overfit_stop_ends_a_member_whose_test_loss_stays_above_its_best(msd, tmp_path):
    # the early-stopping run's settings with no patience: a ratio just above 1 stops the member
    # after 2 evaluations in a row worse than its best; the best model is the one kept
    cfg = blackbox_train_config(epochs=12, lr=0.3, overfit=1 + 1e-9, overfit_evals=2, **F32)
    res = train(msd, cfg, tmp_path / "of")
    m, hist = res.members[0].metrics, res.members[0].history
    assert m["stopped"].startswith(f"early stop at epoch {hist[-1]['epoch']} (overfit: test loss "
                                   "above 1x its best") and m["epochs_run"] < 12
    assert m["best_test_loss"] == min(r["test_loss"] for r in hist)
    assert hist[-1]["epoch"] - m["best_epoch"] == 2
    assert all(r["test_loss"] > m["best_test_loss"] for r in hist[-2:])
    header = ckpt.read_header(tmp_path / "of" / "checkpoint.eqx")
    assert header["over"] == [2]
    # a larger ratio than the run ever saw stops nothing: every epoch runs
    calm = train(msd, blackbox_train_config(epochs=12, lr=0.3, overfit=1e6, **F32),
                 tmp_path / "calm")
    assert calm.members[0].metrics["stopped"] == "completed 12 epochs"


@pytest.mark.parametrize("bad", [1.0, 0.5, -2.0, float("inf"), True, "2"])
def test_overfit_refuses_a_ratio_not_above_one(bad):
    with pytest.raises(UserError, match=r"^overfit: expected a number > 1 \(times the best test "
                                        r"loss\), got"):
        blackbox_train_config(overfit=bad)
    with pytest.raises(UserError, match=r"^overfit_evals: expected an integer >= 1, got 0"):
        blackbox_train_config(overfit=2.0, overfit_evals=0)


def test_test_samples_evaluates_a_seeded_subset_of_the_held_out_pairs(msd, tmp_path):
    # the test loss on a subset: the metrics count it, and the best test loss is the mean eq. 8
    # error of the best model on exactly those pairs (make_pairs' draw with the split seed); a
    # subset at least as large as the test set is the whole test set
    from softpinn.learn._data import make_pairs
    from softpinn.learn._losses import Pairs
    from softpinn.learn._predict import one_step_errors
    from softpinn.learn._splits import split_trajectories

    base = dict(epochs=2, test_trajectories=[3, 4], **F32)
    full = train(msd, blackbox_train_config(**base), tmp_path / "full")
    total = full.metrics["test_pairs"]
    sub = train(msd, blackbox_train_config(test_samples=50, **base), tmp_path / "sub")
    assert sub.metrics["test_pairs"] == 50 < total
    _, test_ids = split_trajectories(msd, test=[3, 4], seed=0)
    all_pairs = make_pairs(msd, test_ids)
    some = make_pairs(msd, test_ids, samples=50, seed=0)
    assert np.isin(some.x0[:, 0], all_pairs.x0[:, 0]).all()
    pairs = Pairs(*(jnp.asarray(a, jnp.float32) for a in some[:5]), None)
    best = sub.metrics["best_test_loss"]["mean"]
    assert float(np.mean(one_step_errors(sub.model, pairs))) == pytest.approx(best, rel=1e-4)
    assert best != full.metrics["best_test_loss"]["mean"]
    same = train(msd, blackbox_train_config(test_samples=10 * total, **base), tmp_path / "same")
    assert same.metrics["test_pairs"] == total
    assert [r["test_loss"] for r in same.members[0].history] == \
        [r["test_loss"] for r in full.members[0].history]


def test_target_loss_stops_a_member_when_reached(msd, tmp_path):
    # a first run gives the loss curve; a target between its start and its best stops the
    # same run (same seed and settings) at the first evaluation at or below it
    free = train(msd, blackbox_train_config(), tmp_path / "free").members[0].history
    target = 0.5 * (free[0]["test_loss"] + min(r["test_loss"] for r in free))
    first = next(r for r in free if r["test_loss"] <= target)
    res = train(msd, blackbox_train_config(target_loss=target), tmp_path / "t")
    m = res.members[0].metrics
    assert m["stopped"].startswith(f"reached test loss {first['test_loss']:.4g} <= {target:g} "
                                   f"at epoch {first['epoch']} (adamw)")
    assert res.members[0].history[-1]["epoch"] == first["epoch"] < free[-1]["epoch"]
    # a member that reached its target in AdamW does not go on to L-BFGS
    res = train(msd, blackbox_train_config(target_loss=target, lbfgs_steps=20), tmp_path / "tl")
    assert [r["phase"] for r in res.members[0].history].count("lbfgs") == 0
    # and one that reaches it in L-BFGS stops there, before its budget
    adam_best = min(r["test_loss"] for r in free)
    lb = train(msd, blackbox_train_config(lbfgs_steps=40), tmp_path / "lb").members[0].history
    lb_hist = [r for r in lb if r["phase"] == "lbfgs"]
    goal = 0.5 * (adam_best + min(r["test_loss"] for r in lb_hist))
    assert goal < adam_best  # L-BFGS improves on AdamW here: the goal is reached in L-BFGS
    res = train(msd, blackbox_train_config(lbfgs_steps=40, target_loss=goal), tmp_path / "g")
    m = res.members[0].metrics
    assert m["stopped"].endswith("(lbfgs)") and m["best_test_loss"] <= goal
    assert len([r for r in res.members[0].history if r["phase"] == "lbfgs"]) < len(lb_hist)


@pytest.mark.parametrize("bad", [0.0, -1e-3, float("nan"), float("inf"), True, "1e-3"])
def test_target_loss_refuses_what_is_not_a_positive_number(bad):
    with pytest.raises(UserError, match=r"^target_loss: expected a number > 0, got"):
        blackbox_train_config(target_loss=bad)


def test_lbfgs_finish_accel_and_rollout_losses(msd, tmp_path):
    cfg = blackbox_train_config(lbfgs_steps=20)
    infos = []
    res = train(msd, cfg, tmp_path / "lb", progress=infos.append)
    # the progress callback counts the L-BFGS iterations, for their own bar
    lb_infos = [i for i in infos if i.phase == "lbfgs"]
    assert [i.done for i in lb_infos] == [10, 20] and {i.unit for i in lb_infos} == {"iteration"}
    assert all(i.total == 20 for i in lb_infos)
    adam_infos = [i for i in infos if i.phase == "adamw"]
    assert [i.done for i in adam_infos] == [i.epoch for i in adam_infos]
    assert all(i.total == cfg.epochs and i.unit == "epoch" for i in adam_infos)
    hist = res.members[0].history
    adam = [r for r in hist if r["phase"] == "adamw"]
    lb = [r for r in hist if r["phase"] == "lbfgs"]
    assert len(lb) == 2 and lb[0]["epoch"] == 13
    assert res.metrics["best_test_loss"]["mean"] < min(r["test_loss"] for r in adam) / 2

    res = train(msd, blackbox_train_config(loss="accel", lr=3e-2), tmp_path / "acc")
    h = res.members[0].history  # eq. 10: squared error of (q̇, q̈)
    assert h[-1]["test_loss"] < h[0]["test_loss"] / 5
    # q̈ labels from central differences of q̇ (velocity-only data): learns as well
    res = train(msd, blackbox_train_config(loss="accel", lr=3e-2, accel_labels="differences"),
                tmp_path / "acc-fd")
    h = res.members[0].history
    assert h[-1]["test_loss"] < h[0]["test_loss"] / 5
    assert res.config.accel_labels == "differences"
    res = train(msd, blackbox_train_config(loss="rollout", rollout_steps=4), tmp_path / "ro")
    h = res.members[0].history  # multi-step loss over windows of 5 samples
    assert h[-1]["test_loss"] < h[0]["test_loss"] / 2
    assert res.metrics["pairs"]["train"] == 4 * (81 - 4)  # windows inside 4 trajectories
    with pytest.raises(UserError, match="on momentum data needs accel_labels 'differences'"):
        blackbox_train_config(loss="accel", model=tiny_model_config("hamiltonian"))


def test_accel_training_scored_with_the_pair_loss(msd, tmp_path):
    # test_with "pair": eq. 10 trains, the held-out pairs are scored by eq. 8 (one RK4 step):
    # the same training, another test column, and the best model is the one that predicts best
    from softpinn.learn._data import make_pairs
    from softpinn.learn._losses import pair_loss
    from softpinn.learn._objective import to_pairs
    from softpinn.learn._splits import split_trajectories

    kw = dict(loss="accel", lr=3e-2, input_hold="linear", checkpoint_every=4)
    plain = train(msd, blackbox_train_config(**kw), tmp_path / "a").members[0]
    res = train(msd, blackbox_train_config(test_with="pair", **kw), tmp_path / "b")
    scored = res.members[0]
    assert [r["train_loss"] for r in scored.history] == [r["train_loss"]
                                                         for r in plain.history]
    _, test_ids = split_trajectories(msd, test=(4,))
    pairs = to_pairs(make_pairs(msd, test_ids), "float64")
    best = float(pair_loss(scored.model, pairs, input_hold="linear"))
    assert scored.metrics["best_test_loss"] == pytest.approx(best, rel=1e-9)
    assert min(r["test_loss"] for r in scored.history) == pytest.approx(best, rel=1e-9)
    # the eq. 10 run's own test column is another number (q̈ errors, not state errors)
    assert plain.metrics["best_test_loss"] != pytest.approx(best, rel=1e-2)
    assert ckpt.read_json(tmp_path / "b" / "config.json")["train"]["test_with"] == "pair"
    with pytest.raises(UserError, match=r"^test_with: 'pair' scores held-out pairs; loss "
                                        r"'rollout' holds out windows"):
        blackbox_train_config(loss="rollout", test_with="pair")
    with pytest.raises(UserError, match=r"^test_with: expected one of \['loss', 'pair', "
                                        r"'rollout'\]"):
        blackbox_train_config(test_with="steps")


def test_rollout_scoring_picks_the_model_that_rolls_out_best(msd, tmp_path):
    # test_with "rollout": the pair loss trains, held-out windows of test_steps steps are
    # scored by predict's rollout error in q, and that picks the best epoch
    from softpinn.learn._data import make_windows
    from softpinn.learn._losses import rollout_errors
    from softpinn.learn._objective import to_windows
    from softpinn.learn._splits import split_trajectories

    kw = dict(input_hold="linear", checkpoint_every=4)
    plain = train(msd, blackbox_train_config(**kw), tmp_path / "a").members[0]
    res = train(msd, blackbox_train_config(test_with="rollout", **kw), tmp_path / "b")
    scored = res.members[0]
    # the same training (epoch 0's full-set loss summed in other chunks: the last bits differ)
    np.testing.assert_allclose([r["train_loss"] for r in scored.history],
                               [r["train_loss"] for r in plain.history], rtol=1e-12)
    # the default: 5 s at the data's step, capped by the 4 s held-out trajectory (81 samples)
    assert res.config.test_steps == 80
    stored = ckpt.read_json(tmp_path / "b" / "config.json")["train"]
    assert (stored["test_with"], stored["test_steps"]) == ("rollout", 80)
    _, test_ids = split_trajectories(msd, test=(4,))
    windows = to_windows(make_windows(msd, test_ids, horizon=80), "float64")
    best = float(jnp.mean(rollout_errors(scored.model, windows, horizon=80, weight=0.0,
                                         input_hold="linear")))
    assert scored.metrics["best_test_loss"] == pytest.approx(best, rel=1e-9)
    assert min(r["test_loss"] for r in scored.history) == pytest.approx(best, rel=1e-9)
    assert plain.metrics["best_test_loss"] != pytest.approx(best, rel=1e-2)
    with pytest.raises(UserError, match=r"^test_steps: the windows of test_with 'rollout', "
                                        r"not 'loss'"):
        blackbox_train_config(test_steps=10)
    with pytest.raises(UserError, match=r"^test_steps: expected an integer >= 1"):
        blackbox_train_config(test_with="rollout", test_steps=0)
    with pytest.raises(UserError, match=r"^test_steps: 500 steps is longer than every "
                                        r"held-out trajectory \(at most 80 steps\)"):
        train(msd, blackbox_train_config(test_with="rollout", test_steps=500), tmp_path / "c")
    assert not (tmp_path / "c" / "config.json").exists()


def test_lbfgs_compiles_once(msd, tmp_path):
    # its chunks are one compiled program: the initial state's weak types used to make the
    # second chunk compile it again (16-28 s of every task 4 L-BFGS finish)
    from softpinn.learn._programs import ProgramCache

    cache = ProgramCache()
    train(msd, blackbox_train_config(epochs=1, lbfgs_steps=30), tmp_path / "r", programs=cache)
    (prog,) = cache.entries.values()
    assert prog._lbfgs_fn._cache_size() == 1


def test_lbfgs_alone_from_an_earlier_run(msd, tmp_path):
    # epochs 0 with L-BFGS iterations: no AdamW step, L-BFGS from the --init model
    first = train(msd, blackbox_train_config(), tmp_path / "a")
    res = train(msd, blackbox_train_config(epochs=0, lbfgs_steps=20, init=str(tmp_path / "a")),
                tmp_path / "b")
    hist = res.members[0].history
    assert [r["phase"] for r in hist] == ["adamw", "lbfgs", "lbfgs"]
    assert hist[0]["test_loss"] == pytest.approx(first.metrics["best_test_loss"]["mean"],
                                                 rel=1e-9)
    assert res.members[0].metrics["epochs_run"] == 0
    assert res.metrics["best_test_loss"]["mean"] < hist[0]["test_loss"]
    with pytest.raises(UserError, match=r"epochs: expected an integer >= 1, got 0 \(0 trains "
                                        r"by L-BFGS alone, with lbfgs_steps > 0\)"):
        blackbox_train_config(epochs=0)


def test_bad_config_values():
    with pytest.raises(UserError, match="epochs: expected an integer >= 1, got 0"):
        blackbox_train_config(epochs=0)
    with pytest.raises(UserError, match="schedule: expected one of"):
        blackbox_train_config(schedule="linear")
    with pytest.raises(UserError, match="lr: expected a finite number > 0"):
        blackbox_train_config(lr=-1.0)
    with pytest.raises(UserError, match="accel_labels: expected one of"):
        blackbox_train_config(loss="accel", accel_labels="smoothed")
    with pytest.raises(UserError, match="accel_labels: 'differences' is for loss 'accel', not "
                                        "'pair'"):
        blackbox_train_config(accel_labels="differences")
    # non-finite values are refused where they enter, naming the field
    for name in ("lr", "weight_decay", "clip_norm", "loss_weight"):
        for bad in (float("nan"), float("inf")):
            with pytest.raises(UserError, match=rf"{name}: expected a finite number"):
                blackbox_train_config(**{name: bad})
    for bad in (0, -3, 2.5, True):
        with pytest.raises(UserError, match=rf"test_samples: expected an integer >= 1, got "
                                            rf"{bad!r}"):
            blackbox_train_config(test_samples=bad)
    with pytest.raises(UserError, match="warmup: expected a fraction"):
        blackbox_train_config(warmup=float("nan"))
    cfg = blackbox_train_config(test_trajectories=[1, 2])
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
