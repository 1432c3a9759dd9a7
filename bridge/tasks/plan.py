"""The plan of a task run: what ``reproduce`` does with a spec, read from its recipe
(``[training]``, :mod:`symbolic.spec._recipe`) and ``[data]`` tables and the call's settings."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from softpinn.actuator import Actuator
from softpinn.bridge.tasks.budget import ModelBudget
from softpinn.errors import UserError
from softpinn.learn import PRIOR_SETTINGS
from softpinn.symbolic import LOSS_KEYS, MODEL_KEYS, data_config, load_spec, physics_data_table

TASKS = ("task1", "task2", "task3", "task4", "task5")
#: studies ``reproduce`` runs with their own pipeline (the paper's experiment: .experiment)
EXPERIMENTS = ("experiment",)
#: The open-challenges studies (:mod:`bridge.challenges`): not a task of the paper's own.
CHALLENGES = ("challenges",)
#: The Cosserat-rod stand-in study (:mod:`bridge.cosserat`, issue 43): a study of its own.
COSSERAT = ("cosserat",)
PHYSICS_KINDS = ("lagrangian", "hamiltonian")

#: The paper's smallest networks (4 wide for Task 1) did not reach its losses in our budgets;
#: mass and potential networks get at least this width (Table III's sizes are in the report).
MIN_WIDTH = 32

#: λ of the one-step errors a report shows (train, test, floor, no forces): the same for every
#: model of a task whatever λ it trained with, so the columns compare.
REPORT_WEIGHT = 1.0

#: A full run's optimizer steps per network where the recipe gives no epochs (a spec of one's
#: own): task 4's recipe takes 400 epochs of 125 steps, task 1's 600 of 156.
DEFAULT_STEPS = 50_000


def default_epochs(spec, data: Mapping[str, Any], kind: str, batch_size: int) -> int:
    """Epochs of a full run's ``kind`` network when the recipe names none: about
    :data:`DEFAULT_STEPS` optimizer steps on the training pairs the ``[data]`` table makes (the
    most of its rates), 20 to 1,000 epochs. A fixed count would make a run on a large data set
    of one's own take hours (1,000 epochs of 40,000 pairs: 625,000 steps)."""

    cfg = data_config(spec, data)
    trajectories = cfg.train_trajectories or 1
    if kind == "blackbox" and cfg.blackbox_train_trajectories:
        trajectories = cfg.blackbox_train_trajectories
    pairs = trajectories * max(1, round(cfg.duration * max(cfg.rates)) - 1)
    if kind != "blackbox" and cfg.physics_samples:
        pairs = min(pairs, cfg.physics_samples)
    steps_per_epoch = math.ceil(pairs / batch_size)
    return int(min(1000, max(20, round(DEFAULT_STEPS / steps_per_epoch))))


def is_spec_file(task: str) -> bool:
    """Whether ``reproduce``'s TASK names a spec file of the user's (``myarm.toml``, a path
    ending in .toml) rather than a preset: its ``[data]`` and ``[training]`` recipe are run as a
    task's."""
    return str(task).lower().endswith(".toml")


def task_spec(task: str, log=None):
    """The spec a ``reproduce`` of ``task`` runs: a preset, or a spec file of the user's. A spec
    without a ``[data]`` table gets the data ``softpinn simulate`` would draw for it, scaled to
    its physics (:mod:`symbolic.simulation._defaults`; the summary line goes to ``log``)."""

    spec = load_spec(task)
    if not spec.data:

        table, summary = physics_data_table(spec)
        spec = dataclasses.replace(spec, data=table)
        if log is not None:
            log(summary)
    return spec


@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of one ``reproduce`` call (everything else comes from the task's preset, or
    from the spec file ``task`` names: :func:`is_spec_file`)."""

    task: str
    quick: bool = False
    seeds: int = 1
    epochs: int | None = None  # overrides every model's epochs
    lbfgs_steps: int | None = None  # overrides every model's L-BFGS iterations
    float32: bool = False
    analysis_points: int | None = None  # sampled q for the analysis (default 200, quick 40)
    jobs: int = 1  # models trained and analysed side by side, each in a process of its own
    #: the experiment's actuator, TAU:DELAY in s (``--actuator``, softpinn/actuator.py): the
    #: stand-in's tendons follow their commands through this lag and dead time
    actuator: str | None = None
    #: the linear prior of the networks (``--prior``, learn/_prior.py): the experiment's
    #: default is none (the paper's networks), the Cosserat study's auto (linear on imports)
    prior: str | None = None

    def __post_init__(self):
        studies = TASKS + EXPERIMENTS + CHALLENGES + COSSERAT
        if self.task not in studies and not is_spec_file(self.task):
            known = ", ".join(studies)
            raise UserError(f"task: expected one of {known} or a spec file (.toml), got "
                            f"{self.task!r}")
        if self.task in CHALLENGES + COSSERAT:
            given = [flag for flag, v in (("--seeds", self.seeds != 1), ("--epochs", self.epochs),
                                          ("--lbfgs-steps", self.lbfgs_steps),
                                          ("--float32", self.float32)) if v]
            if given:
                whose = ("the challenges' studies set their" if self.task in CHALLENGES
                         else f"the {self.task} study sets its")
                raise UserError(f"{', '.join(given)}: {whose} own budgets (--quick for small "
                                "ones); leave these out")
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, int) or self.jobs < 1:
            raise UserError(f"--jobs must be an integer >= 1, got {self.jobs!r}")
        if self.jobs > 1 and self.task in CHALLENGES + COSSERAT:
            raise UserError(f"--jobs: {self.task} runs its models one at a time; leave it out")
        if not isinstance(self.seeds, int) or self.seeds < 1:
            raise UserError(f"--seeds must be an integer >= 1, got {self.seeds!r}")
        if self.epochs is not None and (not isinstance(self.epochs, int) or self.epochs < 1):
            raise UserError(f"--epochs must be an integer >= 1, got {self.epochs!r}")
        if self.lbfgs_steps is not None and self.lbfgs_steps < 0:
            raise UserError(f"--lbfgs-steps must be >= 0, got {self.lbfgs_steps!r}")
        if self.actuator is not None:
            if self.task not in EXPERIMENTS:
                raise UserError(f"--actuator: only the experiment's stand-in takes it (`softpinn "
                                f"reproduce experiment --actuator TAU:DELAY`), not {self.task}; "
                                "leave it out")
            try:
                Actuator.parse(self.actuator)
            except UserError as e:  # the same rules as train --actuator, naming this flag
                msg = str(e).removeprefix("actuator: ")
                raise UserError(f"--actuator: {msg}") from None
        if self.prior is not None:
            if self.task not in EXPERIMENTS + COSSERAT:
                raise UserError(f"--prior: only the experiment and cosserat studies take it, "
                                f"not {self.task}; leave it out")
            if self.prior not in PRIOR_SETTINGS:
                raise UserError(f"--prior: expected one of {list(PRIOR_SETTINGS)}, got "
                                f"{self.prior!r}")


# ------------------------------------------------------------------------------------ plan


@dataclass(frozen=True)
class Variant:
    """One data set and the models trained on it (Task 5 has four)."""

    name: str  # "main", or for task5 "fixed_0.0002s", "50Hz", "100Hz", "1000Hz"
    source: str  # "cvodes" or "rk4" (the simulated file it comes from)
    rate: float | None  # resample the source to this rate (None: as simulated)
    models: tuple[str, ...]
    substeps: int | None = None  # RK4 steps per data interval (None: the models' own)


@dataclass(frozen=True)
class Plan:
    """What a task run does: data settings, variants, and each network's budget
    (:class:`.budget.ModelBudget`, by kind)."""

    task: str
    quick: bool
    data: Mapping[str, Any]
    fixed_step: Mapping[str, Any] | None
    variants: tuple[Variant, ...]
    models: Mapping[str, ModelBudget]
    batch_size: int
    horizon: float
    long_horizon: float
    other_dt: float | None
    analysis_points: int
    physics_samples: int | None
    seeds: int
    float32: bool

    def to_dict(self) -> dict[str, Any]:
        """The plan as ``plan.json`` holds it (each model's budget: :meth:`ModelBudget.to_dict`)."""
        d = dataclasses.asdict(dataclasses.replace(self, models={}))
        d["models"] = {kind: m.to_dict() for kind, m in self.models.items()}
        return json.loads(json.dumps(d, default=list))


#: [data]'s output rate [Hz] when it names none (symbolic.simulation._datatable's default)
DEFAULT_RATE = 100.0


def substeps_for(step: float, max_step: float) -> int:
    """RK4 sub-steps over a data step so that none is longer than ``max_step``: at least 1."""
    return max(1, math.ceil(step / max_step - 1e-9))


def data_step(plan: Plan, variant: Variant) -> float:
    """The time between two samples of a variant's data [s]: its rate's, the fixed-step data's
    output step, or the single data set's [data] rate."""
    if variant.rate:
        return 1.0 / variant.rate
    if variant.source == "rk4" and plan.fixed_step:
        return 1.0 / float(plan.fixed_step["rate"])
    return 1.0 / float(plan.data.get("rate", DEFAULT_RATE))


def own_substeps(m: ModelBudget, step: float) -> int:
    """RK4 sub-steps of a model ``m`` with a ``max_step`` of its own over a data step."""
    return max(int(m.substeps), substeps_for(step, float(m.max_step)))


def make_plan(spec, config: ReproduceConfig) -> Plan:
    """The plan of a task run from its spec's recipe (``[training]``, :mod:`symbolic.spec._recipe`)
    and ``[data]`` tables, and the call's settings. A ``[data]`` table with ``rates`` gives one
    variant per rate (the black box on ``blackbox_rates`` only), and with ``fixed_step_dt`` one
    more on fixed-step RK4 data; otherwise one variant on the data as simulated."""
    task, quick = (spec.name if is_spec_file(config.task) else config.task), config.quick
    recipe = spec.recipe
    data = dict(spec.data)
    physics = recipe.physics
    horizon = recipe.prediction_horizon
    fixed_step = None
    if quick:
        data.update(train_trajectories=3, test_trajectories=2, blackbox_train_trajectories=4)
        data["duration"] = recipe.quick["duration"]
        data.pop("trajectories", None)
        horizon = min(horizon, data["duration"] * 0.6)
        if "rates" in recipe.quick:
            data["rates"] = list(recipe.quick["rates"])
        if "fixed_step_train_trajectories" in recipe.quick:
            data["fixed_step_train_trajectories"] = recipe.quick["fixed_step_train_trajectories"]
    def more_steps(rate):  # a variant's sub-steps from [training]'s max_step (None: one)
        sub = substeps_for(1.0 / rate, recipe.max_step) if recipe.max_step is not None else 1
        return sub if sub > 1 else None

    if "rates" in data:
        variants = []
        if "fixed_step_dt" in data:
            dt = float(data["fixed_step_dt"])
            q = recipe.quick if quick else {}
            fixed_step = {
                "dt": dt,
                "rate": float(q.get("fixed_step_rate", data.get("fixed_step_rate", 1.0 / dt))),
                "duration": float(q.get("fixed_step_duration", data["duration"] if quick
                                        else min(10.0, float(data["duration"])))),
                "trajectories": int(q.get("fixed_step_trajectories",
                                          data.get("fixed_step_trajectories", 5))),
            }
            variants.append(Variant(f"fixed_{dt:g}s", "rk4", None, physics + ("blackbox",)))
        black = recipe.blackbox_rates
        for r in (float(r) for r in data["rates"]):
            kinds = physics + (("blackbox",) if black is None or r in black else ())
            variants.append(Variant(f"{r:g}Hz", "cvodes", r, kinds, more_steps(r)))
        variants = tuple(variants)
    else:
        rate = float(data.get("rate", DEFAULT_RATE))
        variants = (Variant("main", "cvodes", None, physics + ("blackbox",), more_steps(rate)),)
    models = {kind: _model_budget(spec, config, data, kind)
              for kind in physics + ("blackbox",)}
    other_dt = recipe.other_dt
    if other_dt is None:
        rate = float(data.get("rate", max(data.get("rates", [DEFAULT_RATE]))))
        other_dt = 2.0 / rate
    return Plan(
        task=task,
        quick=quick,
        data=data,
        fixed_step=fixed_step,
        variants=variants,
        models=models,
        batch_size=recipe.batch_size,
        horizon=horizon,
        long_horizon=min(3 * horizon, float(data["duration"])),
        other_dt=other_dt,
        analysis_points=config.analysis_points or (40 if quick else 200),
        physics_samples=None if quick else data.get("physics_samples"),
        seeds=config.seeds,
        float32=config.float32,
    )




def _model_budget(spec, config: ReproduceConfig, data: Mapping[str, Any],
                  kind: str) -> ModelBudget:
    """Network ``kind``'s budget in a run of ``spec`` (``data``: the run's ``[data]`` table):
    quick settings or the recipe's full-run sizes and budget, the network's loss and model
    settings, and the call's overrides (``--epochs``, ``--lbfgs-steps``)."""
    recipe, quick = spec.recipe, config.quick
    budget = recipe.full.get(kind, {})
    own = recipe.networks.get(kind, {})
    net = kind if kind != "blackbox" else recipe.physics[0]
    if quick:
        sizes = dict(mass=(16, 2), potential=(16, 2), damping=(8, 2), input=(8, 2),
                     hidden=(32, 2))
        epochs, lbfgs, lr = int(recipe.quick["epochs"]), 0, 3e-3
    else:
        sizes = dict(mass=recipe.network(net, "mass", (64, 3)),
                     potential=recipe.network(net, "potential", (64, 3)),
                     damping=recipe.network(net, "damping", (16, 2)),
                     input=recipe.network(net, "input", (16, 2)),
                     hidden=recipe.network("blackbox", "hidden", (128, 3)))
        for name in ("mass", "potential"):
            sizes[name] = (max(sizes[name][0], MIN_WIDTH), sizes[name][1])
        epochs = int(budget["epochs"]) if "epochs" in budget else default_epochs(
            spec, data, kind, recipe.batch_size)
        lbfgs, lr = int(budget.get("lbfgs_steps", 0)), float(budget.get("lr", 2e-3))
    # the loss a network learns from (eq. 8/9 unless the recipe says otherwise), and how it is
    # built and takes the data (a known A, the damping's form, momenta)
    given = {k: own[k] for k in LOSS_KEYS if k in own}
    given.update({k: v for k, v in own.items() if k in MODEL_KEYS})
    mass_init = None
    if kind == "hamiltonian" and given.get("momenta") != "velocity":
        mass_init = "data"  # M⁻¹'s initial diagonal from the data (learn.mass_scale)
    elif kind == "lagrangian" and given.get("known_input"):
        # with A known, M itself carries the data's scale (RESULTS.md: "The start of M
        # matters with A known")
        mass_init = "data"
    # a full run's stopping rules: evaluations without a better test loss (patience), stop
    # once the test loss stays above X x best (overfit), held-out pairs of the test loss
    stops = {} if quick else {k: (float if k == "overfit" else int)(budget[k])
                              for k in ("patience", "overfit", "test_samples") if k in budget}
    equal_steps = bool(budget.get("equal_steps", False)) and not quick
    if config.epochs is not None:
        epochs, equal_steps = config.epochs, False
    if config.lbfgs_steps is not None:
        lbfgs = config.lbfgs_steps
    return ModelBudget(
        **sizes, epochs=epochs, lbfgs=lbfgs, lr=lr, paper_epochs=recipe.network(kind, "epochs"),
        substeps=recipe.substeps, input_hold=recipe.input_hold,
        # this network's own longest RK4 step
        max_step=float(own["max_step"]) if "max_step" in own else None,
        **given, mass_init=mass_init, equal_steps=equal_steps, **stops,
    )
