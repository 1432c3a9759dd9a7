"""The task recipe (a spec's [training] table): typed, validated when the spec loads, and the
only source of the pipeline's per-task settings."""

from __future__ import annotations

import dataclasses
import math

import pytest

from softpinn.bridge.tasks import ReproduceConfig, make_plan, variant_model
from softpinn.learn import ModelConfig, TrainConfig
from softpinn.symbolic import SpecError, load_spec
from softpinn.symbolic.spec._recipe import BUDGET_KEYS, LOSS_KEYS, MODEL_KEYS, Recipe
from softpinn.symbolic.spec._spec import preset_path

TASKS = ("task1", "task2", "task3", "task4", "task5")


def _spec_with(tmp_path, training: str, base: str = "task1"):
    text = preset_path(base).read_text()
    head = text[: text.index("[training]")]
    path = tmp_path / "arm.toml"
    path.write_text(head + training)
    return path


@pytest.mark.parametrize(
    ("training", "field", "message"),
    [
        ("[training]\nbacth_size = 64\n", "training.bacth_size", "unknown key"),
        ("[training]\n[training.lagrangian]\nepohcs = 10\n", "training.lagrangian.epohcs",
         "unknown key"),
        ("[training]\n[training.full.lagrangian]\nepohcs = 10\n",
         "training.full.lagrangian.epohcs", "unknown key"),
        ("[training]\n[training.full.lagrnagian]\nepochs = 10\n", "training.full.lagrnagian",
         "unknown key"),
        ("[training]\nbatch_size = \"64\"\n", "training.batch_size", "expected an integer"),
        ("[training]\nbatch_size = 0\n", "training.batch_size", "at least 1"),
        ("[training]\nprediction_horizon = nan\n", "training.prediction_horizon", "finite"),
        ("[training]\nprediction_horizon = -1.0\n", "training.prediction_horizon", "positive"),
        ("[training]\nphysics = [\"lagrange\"]\n", "training.physics", "lagrangian"),
        ("[training]\nmatrix_q = [[0.1, 0.2, 0.3]]\n", r"training.matrix_q\[0\]", "2 numbers"),
        ("[training]\ninput_hold = \"cubic\"\n", "training.input_hold", "constant, linear"),
        ("[training]\n[training.lagrangian]\nmass = [30]\n", "training.lagrangian.mass",
         "width, depth"),
        ("[training]\n[training.lagrangian]\nloss = \"l2\"\n", "training.lagrangian.loss",
         "pair, accel, rollout"),
        ("[training]\n[training.full.lagrangian]\nlr = inf\n", "training.full.lagrangian.lr",
         "finite"),
        ("[training]\n[training.full.lagrangian]\nequal_steps = 1\n",
         "training.full.lagrangian.equal_steps", "true or false"),
        ("[training]\n[training.quick]\nepochs = 2.5\n", "training.quick.epochs",
         "expected an integer"),
        ("[training]\n[training.lagrangian]\nmomenta = \"velocity\"\n",
         "training.lagrangian.momenta", "unknown key"),  # a Hamiltonian network's setting
        ("[training]\n[training.blackbox]\nknown_input = true\n",
         "training.blackbox.known_input", "unknown key"),
        ("[training]\n[training.hamiltonian]\nknown_input = \"task4\"\n",
         "training.hamiltonian.known_input", "true or false"),
        ("[training]\n[training.hamiltonian]\ndamping_form = \"dense\"\n",
         "training.hamiltonian.damping_form", "network, constant, none"),
        ("[training]\n[training.hamiltonian]\nmomenta = \"p\"\n",
         "training.hamiltonian.momenta", "auto, data, velocity"),
        ("[training]\n[training.blackbox]\nmax_step = 0.0\n", "training.blackbox.max_step",
         "positive"),
        ("[training]\n[training.blackbox]\nmax_step = \"10 ms\"\n",
         "training.blackbox.max_step", "expected a number"),
        ("[training]\n[training.full.blackbox]\noverfit = 1.0\n",
         "training.full.blackbox.overfit", "greater than 1"),
    ],
)
def test_bad_training_table_is_refused_naming_file_and_field(tmp_path, training, field,
                                                             message):
    path = _spec_with(tmp_path, training)
    with pytest.raises(SpecError, match=rf"arm\.toml: field '{field}': .*{message}"):
        load_spec(path)


def test_bad_training_table_is_one_line_at_the_cli(tmp_path, capsys):
    from softpinn.bridge.cli import main

    path = _spec_with(tmp_path, "[training]\nbacth_size = 64\n")
    assert main(["matrices", str(path), "--q", "0", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "training.bacth_size" in err and "unknown key" in err


@pytest.mark.parametrize("task", TASKS)
def test_presets_carry_a_valid_recipe(task):
    recipe = load_spec(task).recipe
    assert isinstance(recipe, Recipe)
    assert recipe.full, f"{task}: no full-run budget"
    assert math.isfinite(recipe.prediction_horizon) and recipe.prediction_horizon > 0
    assert recipe.batch_size >= 1 and recipe.physics


def test_recipe_training_keys_are_train_config_fields():
    """The recipe names training settings as learn's TrainConfig does (no second default)."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    pipeline_only = {"equal_steps"}  # a pipeline setting: epochs scaled to equal step counts
    assert set(BUDGET_KEYS) - pipeline_only <= fields
    assert set(LOSS_KEYS) <= fields
    model_fields = {f.name for f in dataclasses.fields(ModelConfig)}
    assert set(MODEL_KEYS) <= fields | model_fields


def test_a_model_budget_is_a_partial_train_config():
    """A network's budget in the plan sets only what the recipe or the run sets: its optional
    settings are TrainConfig's or ModelConfig's names (or the pipeline's own), one left out is
    not written to plan.json and trains with TrainConfig's own default."""
    from softpinn.bridge.tasks.budget import OPTIONAL

    names = ({f.name for f in dataclasses.fields(TrainConfig)}
             | {f.name for f in dataclasses.fields(ModelConfig)})
    assert OPTIONAL - {"max_step", "equal_steps"} <= names
    plan = make_plan(load_spec("task1"), ReproduceConfig("task1", quick=True))
    m = plan.models["lagrangian"]
    assert m.loss is None and m.train_settings() == {}
    assert not {"loss", "momenta", "patience"} & set(plan.to_dict()["models"]["lagrangian"])
    defaults = {f.name: f.default for f in dataclasses.fields(TrainConfig)}
    assert (m.trained_with("loss"), m.trained_with("momenta")) == (
        defaults["loss"], defaults["momenta"])
    h = make_plan(load_spec("task3"), ReproduceConfig("task3")).models["hamiltonian"]
    assert h.train_settings() == {"loss_weight": 0.1}  # the recipe's λ, and nothing else
    assert plan.to_dict()["models"]["lagrangian"]["paper_epochs"] == 6000  # always written


def test_a_user_recipe_drives_the_plan(tmp_path):
    path = _spec_with(tmp_path, """[training]
physics = ["hamiltonian"]
prediction_horizon = 1.5
batch_size = 32
substeps = 3
[training.hamiltonian]
mass = [40, 2]
loss_weight = 0.5
[training.full.hamiltonian]
epochs = 77
lbfgs_steps = 5
[training.full.blackbox]
epochs = 11
[training.quick]
epochs = 9
duration = 3.0
""")
    spec = load_spec(path)
    full = make_plan(spec, ReproduceConfig("task1"))
    assert full.batch_size == 32 and full.horizon == 1.5
    h = full.models["hamiltonian"]
    assert (h.epochs, h.lbfgs, h.mass, h.substeps, h.loss_weight) == (77, 5, (40, 2), 3, 0.5)
    assert full.models["blackbox"].epochs == 11
    assert [v.models for v in full.variants] == [("hamiltonian", "blackbox")]
    quick = make_plan(spec, ReproduceConfig("task1", quick=True))
    assert quick.models["hamiltonian"].epochs == 9 and quick.data["duration"] == 3.0
    assert quick.models["hamiltonian"].loss_weight == 0.5  # the loss holds in quick runs


def test_a_recipe_fixes_a_known_input_and_the_damping_form(tmp_path, monkeypatch):
    """[training.<network>] known_input / damping_form / momenta / accel_space reach the trained
    model: the stage's TrainConfig carries this spec's exact A(q), the damping's form, the
    momenta and eq. 10's space, in full and quick runs alike; Table III's model column says so."""
    from types import SimpleNamespace

    import numpy as np

    from softpinn.bridge.exact.serialize import spec_known_input
    from softpinn.bridge.report.task import _model_size
    from softpinn.bridge.tasks import stages

    path = _spec_with(tmp_path, """[training]
physics = ["lagrangian", "hamiltonian"]
[training.lagrangian]
known_input = true
[training.hamiltonian]
known_input = true
damping_form = "constant"
momenta = "velocity"
loss = "accel"
accel_labels = "differences"
accel_space = "force"
test_with = "pair"
""", base="task4")
    spec = load_spec(path)
    for quick in (False, True):
        plan = make_plan(spec, ReproduceConfig("task4", quick=quick))
        lag, ham = plan.models["lagrangian"], plan.models["hamiltonian"]
        assert lag.known_input and lag.mass_init == "data"  # M carries the scale
        assert (ham.known_input, ham.damping_form, ham.momenta) == (
            True, "constant", "velocity")
        assert ham.mass_init is None  # from velocities: no momenta to take a scale from
        assert "known_input" not in plan.models["blackbox"].to_dict()
    assert _model_size("hamiltonian", ham) == "(16*2)*2 + D const + A known, from q̇"
    assert _model_size("lagrangian", lag) == "(16*2)*2 + 8*2 + A known"

    # the stage's configuration, caught where training would start
    seen = {}

    def fake_train(data, tc, run_dir, **kw):
        seen["tc"] = tc
        raise RuntimeError("stop")

    # where the stage finds them
    monkeypatch.setattr(stages, "train", fake_train)
    rng = np.random.default_rng(0)
    fake = SimpleNamespace(p=rng.normal(size=(20, spec.n)), qd=rng.normal(size=(20, spec.n)),
                           traj=np.repeat([0, 1], 10))
    monkeypatch.setattr(stages, "load_dataset", lambda path: fake)
    files = {"physics": {"path": "x.npz", "train": [0], "test": [1], "samples": 10}}
    text = spec_known_input(spec)[0]
    for kind in ("hamiltonian", "lagrangian"):
        with pytest.raises(RuntimeError, match="stop"):
            stages.stage_train(spec, plan, kind, plan.models[kind], files, tmp_path / kind,
                               progress=None)
        tc = seen["tc"]
        assert (tc.model.input_form, tc.model.known_input) == ("known", text)
        assert tc.momenta == ("velocity" if kind == "hamiltonian" else "auto")
        assert tc.model.damping_form == ("constant" if kind == "hamiltonian" else "network")
        assert (tc.model.mass_init is None) == (kind == "hamiltonian")
        assert tc.accel_space == ("force" if kind == "hamiltonian" else "acceleration")
        assert tc.test_with == ("pair" if kind == "hamiltonian" else "loss")


def test_an_interrupted_hamiltonian_run_is_resumed(tmp_path, monkeypatch):
    """The stage's TrainConfig carries a Hamiltonian network's momenta decided for its data, as
    train() stores them in config.json, so an interrupted run compares equal and is resumed
    (with "auto" beside the stored "data" it was trained again from scratch)."""
    import json
    from types import SimpleNamespace

    import numpy as np

    from softpinn.bridge.tasks import stages

    spec = load_spec("task4")
    plan = make_plan(spec, ReproduceConfig("task4", quick=True))
    seen = {}

    def fake_train(data, tc, run_dir, **kw):
        seen["tc"], seen["resume"] = tc, kw.get("resume")
        raise RuntimeError("stop")

    monkeypatch.setattr(stages, "train", fake_train)
    rng = np.random.default_rng(0)
    fake = SimpleNamespace(p=rng.normal(size=(20, spec.n)), qd=rng.normal(size=(20, spec.n)),
                           traj=np.repeat([0, 1], 10), meta={}, path="x.npz")  # simulated p
    monkeypatch.setattr(stages, "load_dataset", lambda path: fake)
    files = {"physics": {"path": "x.npz", "train": [0], "test": [1], "samples": 10}}

    def stage():
        with pytest.raises(RuntimeError, match="stop"):
            stages.stage_train(spec, plan, "hamiltonian", plan.models["hamiltonian"], files,
                               tmp_path, progress=None)
        return seen["tc"], seen["resume"]

    tc, resume = stage()
    assert (tc.momenta, tc.model.state_kind, resume) == ("data", "momentum", False)
    run = tmp_path / "run"  # what an interrupted train() leaves
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"train": tc.to_dict()}))
    (run / "checkpoint.eqx").write_bytes(b"")
    assert stage() == (tc, True)


def test_a_network_steps_by_its_own_max_step(tmp_path):
    """[training.<network>] max_step: that network's sub-steps per data interval, on every
    rate of a multi-rate [data] table, in place of [training]'s; the others keep theirs, and
    the report's integration sentence says so."""
    from softpinn.bridge.report.task import _integration_sentence

    text = preset_path("task5").read_text()
    head, training = text[: text.index("[training]")], text[text.index("[training]"):]
    training = training.replace("max_step = 0.01\n", "")  # the preset's black box's own
    training = training.replace("[training.blackbox]\n", "[training.blackbox]\nmax_step = 0.012\n")
    path = tmp_path / "arm.toml"
    path.write_text(head + training)
    plan = make_plan(load_spec(path), ReproduceConfig("task5"))
    steps = {v.name: {k: variant_model(plan, v, k).substeps for k in v.models}
             for v in plan.variants}
    assert steps == {"fixed_0.0002s": {"lagrangian": 1, "blackbox": 1},
                     "50Hz": {"lagrangian": 3}, "100Hz": {"lagrangian": 2, "blackbox": 1},
                     "1000Hz": {"lagrangian": 1}}
    assert variant_model(plan, plan.variants[2], "blackbox").max_step is None
    sentence = _integration_sentence(plan)
    assert "the 100Hz data with 2" in sentence
    assert "The black box network steps by its own longest step, 0.012 s: 1 on the " \
           "fixed_0.0002s data, 1 on the 100Hz data." in sentence
    # a longest step shorter than the data's: sub-steps of its own (ceil(0.01 / 0.004) = 3),
    # on the fixed-step data too (their 0.2 ms samples over 0.1 ms: 2)
    path.write_text(head + training.replace("max_step = 0.012", "max_step = 0.004"))
    plan = make_plan(load_spec(path), ReproduceConfig("task5"))
    assert variant_model(plan, plan.variants[2], "blackbox").substeps == 3
    path.write_text(head + training.replace("max_step = 0.012", "max_step = 0.0001"))
    plan = make_plan(load_spec(path), ReproduceConfig("task5"))
    assert variant_model(plan, plan.variants[0], "blackbox").substeps == 2


def test_max_step_on_a_single_data_set(tmp_path):
    """One data set (task 4: 200 Hz, 5 ms): [training]'s max_step gives every model its
    sub-steps, a network's own max_step that network's (it was ignored without rates)."""
    text = preset_path("task4").read_text()
    head, training = text[: text.index("[training]")], text[text.index("[training]"):]
    training = training.replace("[training]\n", "[training]\nmax_step = 0.002\n", 1)
    training = training.replace("[training.blackbox]\n", "[training.blackbox]\nmax_step = 0.001\n")
    path = tmp_path / "arm.toml"
    path.write_text(head + training)
    plan = make_plan(load_spec(path), ReproduceConfig("task4"))
    (main,) = plan.variants
    assert main.substeps == 3  # ceil(5 / 2)
    assert {k: variant_model(plan, main, k).substeps for k in main.models} == {
        "lagrangian": 3, "hamiltonian": 3, "blackbox": 5}


def test_task5_variants_come_from_its_data_and_recipe():
    plan = make_plan(load_spec("task5"), ReproduceConfig("task5"))
    assert [(v.name, v.models, v.substeps) for v in plan.variants] == [
        ("fixed_0.0002s", ("lagrangian", "blackbox"), None),
        ("50Hz", ("lagrangian",), 3),
        ("100Hz", ("lagrangian", "blackbox"), 2),
        ("1000Hz", ("lagrangian",), None),
    ]
    quick = make_plan(load_spec("task5"), ReproduceConfig("task5", quick=True))
    assert [v.name for v in quick.variants] == ["fixed_0.0002s", "50Hz", "100Hz"]
    assert quick.fixed_step == {"dt": 2e-4, "rate": 1000.0, "duration": 1.0, "trajectories": 3}
