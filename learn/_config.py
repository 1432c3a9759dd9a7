"""The settings of a training run: :class:`TrainConfig` (with the network's
:class:`learn._model_config.ModelConfig`), validated where they enter.

The loss is eq. 8 (velocity state), eq. 9 (momentum state) or eq. 10 (accelerations), see
:mod:`learn._losses`; the optimizer is AdamW (Section III-B, "Model training") via optax.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from softpinn.errors import UserError
from softpinn.learn._actuator import check_actuator_setting
from softpinn.learn._data import ACCEL_LABELS
from softpinn.learn._losses import ACCEL_SPACES
from softpinn.learn._models import ModelConfig
from softpinn.learn._prior import PRIOR_SETTINGS
from softpinn.learn._splits import check_validation_setting
from softpinn.learn._velocity import MOMENTA

FORMAT = "softpinn-run"
FORMAT_VERSION = 1
SCHEDULES = ("cosine", "exponential", "constant")
LOSSES = ("pair", "accel", "rollout")
ENSEMBLE_MODES = ("auto", "vmap", "sequential")
SEED_MAX = 2**32 - 1
INPUT_HOLDS = ("constant", "linear")
#: held-out data scored with: the training loss, eq. 8/9, or rollouts of ``test_steps`` steps
TEST_WITH = ("loss", "pair", "rollout")
#: The groups of :class:`TrainConfig`'s settings, in the order ``softpinn train --help`` shows.
GROUPS = ("budget", "optimizer", "loss", "split", "ensemble", "devices")
#: Settings that may change when a run is resumed (the others would make it another run).
RESUMABLE = ("epochs", "patience", "overfit", "overfit_evals", "target_loss", "eval_every",
             "checkpoint_every", "lbfgs_steps", "lbfgs_chunk", "devices")


def _f(default, group: str, help: str, choices: tuple[str, ...] | None = None):
    """A setting with its one default, its group and its help: the CLI is built from these
    (``softpinn train``'s flags, defaults and help text come from here and nowhere else)."""
    meta = {"group": group, "help": help}
    if choices is not None:
        meta["choices"] = choices
    return dataclasses.field(default=default, metadata=meta)


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (with the dataset and the seed).

    ``model``: the network (:class:`learn._model_config.ModelConfig`; its n, m must match the data).
    ``epochs``: passes over the training pairs in minibatches of ``batch_size`` (clipped to the
    number of pairs; the remainder of each shuffled epoch is dropped so shapes never change).
    ``batch_size`` None (the default) takes ``max(64, pairs // 100)`` (batches of 64: a
    mass-spring-damper at 1e-8 in 150 epochs, 1,000 stalled at 7e-5; ~100 steps an epoch).
    ``lr``: peak AdamW learning rate; ``schedule``: "cosine" (linear warmup over ``warmup`` of
    all steps, then cosine decay to ``lr * lr_final``), "exponential" (warmup, then exponential
    decay to ``lr * lr_final`` at the last step) or "constant"; ``weight_decay`` of AdamW;
    ``clip_norm`` > 0 clips the global gradient norm.
    ``init``: a run folder whose best model (the same :class:`learn._model_config.ModelConfig`)
    every member starts from instead of a fresh initialisation: a warm start, e.g. a run of the
    acceleration loss (eq. 10, cheap: no RK4 step) before the pair loss (eq. 8/9; issue 18's fast
    Lagrangian training).
    ``loss``: "pair" (eq. 8/9 with weight λ = ``loss_weight``, ``substeps`` RK4 steps per pair,
    ``input_hold`` "constant" or "linear"), "accel" (eq. 10; q̈ labels as ``accel_labels`` says:
    "recorded" in the file or "differences" of the velocities; on momentum data ṗ from
    differences of p, with the recorded q̇ fitting q̇ = M̂⁻¹(q) p at every sample) or "rollout"
    (the multi-step loss: eq. 8/9 averaged over ``rollout_steps`` RK4 steps simulated from the
    first state of windows of consecutive samples of one trajectory; minibatches of windows).
    ``rollout_schedule`` (loss "rollout"): increasing horizons H_1 < ... < H_S in steps; stage i
    trains at H_i from epoch ceil(i * epochs / S) + 1 on, the held-out loss and L-BFGS at H_S
    (= ``rollout_steps``: :func:`learn._objective.rollout_stage`).
    ``equilibrium_weight`` / ``force_weight`` > 0 add the static-equilibrium labels of the data
    file (:func:`learn._losses.label_loss`; Section VI-B's "additional labels") to the training
    loss (not to the test loss, which stays eq. 8/9/10 alone). ``test_with`` "pair" scores
    held-out pairs with eq. 8/9 whatever the training loss (with loss "accel": eq. 10 trains,
    the one-step prediction error picks the model and decides ``target_loss``/``patience``);
    "rollout" scores held-out windows of ``test_steps`` steps by predict's rollout error in q
    (on noisy recordings a one-step loss can improve while rollouts get worse, RESULTS.md).
    ``seed``: first seed; ``seeds``: ensemble size K (seeds seed, seed+1, ...);
    ``ensemble``: "vmap", "sequential" or "auto" (vmap on an accelerator, sequential on CPU,
    where vmapping was measured slower; see benchmarks/bench_train.py).
    ``test_trajectories``: ids (tuple), a count (int), a fraction (float) or None (the file's
    recorded test split, else 20%: :func:`learn._splits.split_trajectories`);
    ``split_seed`` draws the split, the ``samples`` subset of training pairs and the
    ``test_samples`` subset of held-out pairs the test loss is evaluated on (None: all of each,
    about ten windows a horizon for test_with "rollout"; task 5's large test set is costly).
    ``validation``: training trajectories held out to pick the model (best epoch, patience,
    overfit, target loss; the test loss is only recorded): :func:`learn._splits.validation_split`.
    ``patience``: stop a member after that many evaluations without a better test loss (None:
    never); the saved model is the one with the best test loss. ``overfit``: stop a member
    once its test loss has stayed above ``overfit`` times its best for ``overfit_evals``
    evaluations in a row (None: never; task 5's overfitting network: 7x its best 8 epochs
    later). ``target_loss``: stop a member once its test loss is at or below it (None: never;
    RESULTS.md's time to a loss). ``eval_every``, ``checkpoint_every``: epochs between
    test-loss evaluations, checkpoints.
    ``lbfgs_steps``: L-BFGS iterations on the full training set after AdamW (0: none), starting
    from the best AdamW parameters, in calls of ``lbfgs_chunk`` iterations.
    """

    model: ModelConfig
    # budget
    epochs: int = _f(1000, "budget", "passes over the training pairs (AdamW; 0 with "
                     "--lbfgs-steps: L-BFGS alone, e.g. from --init)")
    batch_size: int | None = _f(None, "budget", "minibatch size (pairs per optimizer step; "
                                "default: max(64, pairs // 100))")
    # optimizer
    lr: float = _f(1e-3, "optimizer", "peak learning rate")
    schedule: str = _f("cosine", "optimizer", "learning-rate schedule after the warmup",
                       SCHEDULES)
    warmup: float = _f(0.02, "optimizer", "warmup fraction of all steps")
    lr_final: float = _f(0.01, "optimizer", "final lr as a fraction of lr")
    weight_decay: float = _f(1e-4, "optimizer", "AdamW weight decay")
    init: str | None = _f(None, "optimizer", "start from the best model of an earlier run "
                          "folder with the same network (e.g. loss accel's, eq. 10, before "
                          "the pair loss); default: a fresh, seeded initialisation")
    clip_norm: float = _f(0.0, "optimizer", "global gradient-norm clip (0: none)")
    # loss
    loss: str = _f("pair", "loss", "pair: one RK4 step per pair, eq. 8/9; accel: eq. 10; "
                   "rollout: eq. 8/9 averaged over rollout-steps steps", LOSSES)
    loss_weight: float = _f(1.0, "loss", "lambda of eqs. 8/9")
    rollout_steps: int = _f(5, "loss", "steps per window of loss 'rollout' (multi-step loss)")
    rollout_schedule: tuple[int, ...] | None = _f(
        None, "loss", "horizons in steps of loss 'rollout', e.g. 1,4,16,64: stage i of S trains "
        "at the i-th horizon from epoch i*epochs/S on (spread evenly over the AdamW epochs); "
        "the held-out loss and L-BFGS use the last (default: rollout-steps throughout)")
    actuator: str = _f(
        "auto", "loss", "lag and dead time between the recorded u and the arm "
        "(softpinn/actuator.py): TAU:DELAY in s (comma lists: one per input), none, data (the "
        "file's), identify (fitted to the data) or auto (data, else identify on imports)")
    prior: str = _f(
        "auto", "loss", "linear: the networks start as the linear model M q̈ + D q̇ + K q = "
        "B u + c of the training data (least squares or rollout fit, whichever rolls out "
        "better) and learn the correction (learn/_prior.py); none: from scratch; auto: linear "
        "on imported recordings", PRIOR_SETTINGS)
    substeps: int = _f(1, "loss", "RK4 sub-steps per pair")
    input_hold: str = _f("constant", "loss", "the input between two samples: held or "
                         "interpolated linearly", INPUT_HOLDS)
    accel_labels: str = _f("recorded", "loss", "q̈ labels of loss 'accel': recorded in the "
                           "file, or central differences of q̇ (momentum data: ṗ from "
                           "differences of p, the only choice)", ACCEL_LABELS)
    accel_space: str = _f("acceleration", "loss", "where loss 'accel' compares: q̈ - q̂̈ "
                          "(acceleration), or M̂(q) (q̈ - q̂̈) (force: the residual of eq. 4, "
                          "linear in the networks' M, D, G; a physics model on (q, q̇) with "
                          "--known-input)", ACCEL_SPACES)
    accel_weights: tuple[float, ...] | None = _f(
        None, "loss", "weights of the force-space residual's n coordinates (loss accel, "
        "accel_space force): each coordinate of M̂ (q̈ - q̂̈) times its weight; "
        "--accel-weights-from RUN sets them to mean(s) / s_i, s_i the rms of M̂ q̈ of RUN's "
        "model over the training data (default: all 1)")
    momenta: str = _f("auto", "loss", "momenta p of a Hamiltonian network: from the data file "
                      "(eq. 9), or from the velocities, p = M(q) qd with the network's own mass "
                      "matrix (eq. 8 on q, qd; learn/_velocity.py); auto: data when the file's "
                      "p came with it, velocity when it has none or computed ones (an import)",
                      MOMENTA)
    test_with: str = _f(
        "loss", "loss", "what held-out data are scored with: loss (the training loss), pair "
        "(eq. 8/9 one step: predict's one-step error) or rollout (windows of --test-steps "
        "steps, mean |q - q̂|²: predict's rollout error); the best model, --target-loss, "
        "--patience and history's test_loss follow it", TEST_WITH)
    test_steps: int | None = _f(
        None, "loss", "steps of test_with rollout's windows (default: 5 s at the data's rate, "
        "at most the shortest held-out trajectory; the run records it)")
    equilibrium_weight: float = _f(
        0.0, "loss", "weight of the static-equilibrium labels G(q*) = A(q*) u* of the data file "
        "(eq_q, eq_u): + weight * mean |G - A u|^2 / mean (|G|^2 + |A u|^2) / 2 at the "
        "equilibria (physics models; 0: off)")
    force_weight: float = _f(
        0.0, "loss", "weight of the measured-force labels f* = G(q*) = A(q*) u* of the data "
        "file (eq_force): + weight * (mean |G - f|^2 + mean |A u - f|^2) / (2 mean |f|^2) "
        "(physics models; 0: off)")
    # ensemble
    seed: int = _f(0, "ensemble", "seed of the network initialisation and minibatch order")
    seeds: int = _f(1, "ensemble", "ensemble size K (seeds S..S+K-1)")
    ensemble: str = _f("auto", "ensemble", "train the seeds as one stacked model (vmap) or one "
                       "after another (auto: vmap on an accelerator)", ENSEMBLE_MODES)
    # split
    test_trajectories: tuple[int, ...] | int | float | None = _f(
        None, "split", "held-out trajectories: ids, a count, a fraction (default: the file's "
        "recorded test split, else 20%)")
    validation: tuple[int, ...] | int | float | str | None = _f(
        None, "split", "training trajectories held out to pick the best epoch and decide "
        "patience, overfit, target loss (test ones are then only scored): ids, a count, a "
        "fraction, 0 (none: the test loss picks) or auto (20% when 3 or more train); "
        "default: auto on recordings of softpinn import, none on simulated data (their spec's "
        "split)")
    split_seed: int = _f(0, "split", "seed of the random train/test split of trajectories")
    samples: int | None = _f(None, "split", "train on N randomly chosen pairs (default: all)")
    test_samples: int | None = _f(None, "split", "evaluate the test loss on N randomly chosen "
                                  "held-out pairs (default: all)")
    # budget, continued (may change on resume)
    patience: int | None = _f(None, "budget", "early-stopping patience in evaluations "
                              "(default: none)")
    overfit: float | None = _f(None, "budget", "stop a member once its test loss has stayed "
                               "above X times its best for --overfit-evals evaluations in a "
                               "row (overfitting; default: none)")
    overfit_evals: int = _f(3, "budget", "evaluations in a row above --overfit times the best "
                            "test loss that stop a member")
    target_loss: float | None = _f(None, "budget", "stop a member once its test loss is at or "
                                   "below X, in AdamW or L-BFGS (default: none)")
    eval_every: int = _f(1, "budget", "evaluate the test loss every N epochs")
    checkpoint_every: int = _f(25, "budget", "write a checkpoint every N epochs")
    lbfgs_steps: int = _f(0, "budget", "L-BFGS iterations after AdamW (0: none)")
    lbfgs_chunk: int = _f(10, "budget", "L-BFGS iterations per compiled call")
    # devices
    devices: int = _f(1, "devices", "devices (GPUs, or CPU devices) to split each minibatch "
                      "over, data parallel on one host; 0: all there are")

    def __post_init__(self):
        if not isinstance(self.model, ModelConfig):
            raise UserError(f"TrainConfig.model must be a ModelConfig, got {type(self.model)}")
        if self.batch_size is not None and (
                isinstance(self.batch_size, bool) or not isinstance(self.batch_size, int)
                or self.batch_size < 1):
            raise UserError(f"batch_size: expected an integer >= 1 or None (auto), got "
                            f"{self.batch_size!r}")
        pos_int = ("substeps", "seeds", "eval_every", "checkpoint_every", "rollout_steps",
                   "overfit_evals")
        for name in pos_int + ("lbfgs_chunk",):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise UserError(f"{name}: expected an integer >= 1, got {v!r}")
        if isinstance(self.epochs, bool) or not isinstance(self.epochs, int) or self.epochs < 0 \
                or (self.epochs == 0 and not (isinstance(self.lbfgs_steps, int)
                                              and self.lbfgs_steps > 0)):
            raise UserError(f"epochs: expected an integer >= 1, got {self.epochs!r} (0 trains "
                            "by L-BFGS alone, with lbfgs_steps > 0)")
        for name in ("lbfgs_steps", "seed", "split_seed", "devices"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise UserError(f"{name}: expected an integer >= 0, got {v!r}")
        # seeds become 32-bit PRNG keys (seed, seed + 1, ..., seed + seeds - 1)
        for name, top in (("seed", SEED_MAX - (self.seeds - 1)), ("split_seed", SEED_MAX)):
            if getattr(self, name) > top:
                raise UserError(
                    f"{name}: expected an integer <= {top} (seeds are 32-bit), "
                    f"got {getattr(self, name)!r}"
                )
        if isinstance(self.lr, bool) or not isinstance(self.lr, (int, float)) or not (
                self.lr > 0 and math.isfinite(self.lr)):
            raise UserError(f"lr: expected a finite number > 0, got {self.lr!r}")
        if not 0 <= self.warmup < 1:
            raise UserError(f"warmup: expected a fraction in [0, 1), got {self.warmup!r}")
        if not 0 < self.lr_final <= 1:
            raise UserError(f"lr_final: expected a number in (0, 1], got {self.lr_final!r}")
        for name in ("weight_decay", "clip_norm", "loss_weight", "equilibrium_weight",
                     "force_weight"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                    math.isfinite(v) and v >= 0):
                raise UserError(f"{name}: expected a finite number >= 0, got {v!r}")
        for name, allowed in (
            ("schedule", SCHEDULES),
            ("loss", LOSSES),
            ("ensemble", ENSEMBLE_MODES),
            ("input_hold", INPUT_HOLDS),
            ("accel_labels", ACCEL_LABELS),
            ("accel_space", ACCEL_SPACES),
            ("momenta", MOMENTA),
            ("test_with", TEST_WITH),
            ("prior", PRIOR_SETTINGS),
        ):
            if getattr(self, name) not in allowed:
                raise UserError(
                    f"{name}: expected one of {list(allowed)}, got {getattr(self, name)!r}"
                )
        if self.patience is not None and (
                isinstance(self.patience, bool) or not isinstance(self.patience, int)
                or self.patience < 1):
            raise UserError(f"patience: expected an integer >= 1, got {self.patience!r}")
        if self.overfit is not None and (
                isinstance(self.overfit, bool) or not isinstance(self.overfit, int | float)
                or not math.isfinite(self.overfit) or self.overfit <= 1):
            raise UserError(f"overfit: expected a number > 1 (times the best test loss), got "
                            f"{self.overfit!r}")
        if self.target_loss is not None and (
                isinstance(self.target_loss, bool)
                or not isinstance(self.target_loss, int | float)
                or not math.isfinite(self.target_loss) or self.target_loss <= 0):
            raise UserError(f"target_loss: expected a number > 0, got {self.target_loss!r}")
        if self.test_steps is not None and self.test_with != "rollout":
            raise UserError(f"test_steps: the windows of test_with 'rollout', not "
                            f"{self.test_with!r}")
        for name in ("samples", "test_samples", "test_steps"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                      or value < 1):
                raise UserError(f"{name}: expected an integer >= 1, got {value!r}")
        if self.init is not None and (not isinstance(self.init, str) or not self.init):
            raise UserError(f"init: expected a run folder, got {self.init!r}")
        if isinstance(self.test_trajectories, list):
            object.__setattr__(self, "test_trajectories", tuple(self.test_trajectories))
        object.__setattr__(self, "validation", check_validation_setting(self.validation))
        check_actuator_setting(self.actuator, self.model.m)
        self._check_accel_weights()
        if self.accel_labels != "recorded" and self.loss != "accel":
            raise UserError(
                f"accel_labels: {self.accel_labels!r} is for loss 'accel', not {self.loss!r}"
            )
        self._check_momenta()
        self._check_accel_space()
        self._check_rollout_schedule()
        if self.test_with == "pair" and self.loss == "rollout":
            raise UserError("test_with: 'pair' scores held-out pairs; loss 'rollout' holds out "
                            "windows, which the rollout loss itself scores")
        for name in ("equilibrium_weight", "force_weight"):
            if getattr(self, name) > 0 and self.model.kind == "blackbox":
                raise UserError(f"{name}: the equilibrium labels weigh G and A of a physics "
                                "model; a blackbox model has none (leave it 0)")
        if (self.loss == "accel" and self.model.state_kind != "velocity"
                and self.accel_labels != "differences"):
            raise UserError(
                "loss: 'accel' (eq. 10) on momentum data needs accel_labels 'differences' "
                "(the file stores q̇ but no ṗ; ṗ is then differenced from p)"
            )

    def _check_rollout_schedule(self):
        """``rollout_schedule``: None, or increasing horizons >= 1 of loss "rollout"; its last
        is the windows' length, ``rollout_steps`` (left at its default 5, it is set to it)."""
        h = self.rollout_schedule
        if h is None:
            return
        if isinstance(h, list):
            h = tuple(h)
        flag = "rollout_schedule (--rollout-schedule)"
        if not isinstance(h, tuple) or not h or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in h):
            raise UserError(f"{flag}: expected horizons in steps, integers >= 1 such as "
                            f"1,4,16,64, got {self.rollout_schedule!r}")
        if any(b <= a for a, b in zip(h, h[1:], strict=False)):
            raise UserError(f"{flag}: the horizons must increase, got {','.join(map(str, h))}")
        if self.loss != "rollout":
            raise UserError(f"{flag}: a schedule of horizons is for loss 'rollout' (--loss "
                            f"rollout), not {self.loss!r}")
        if self.rollout_steps not in (5, h[-1]):
            raise UserError(f"{flag}: its last horizon ({h[-1]}) is the rollout's length; "
                            f"leave out --rollout-steps ({self.rollout_steps}) or give {h[-1]}")
        object.__setattr__(self, "rollout_schedule", h)
        object.__setattr__(self, "rollout_steps", h[-1])

    def _check_accel_space(self):
        """``accel_space`` "force" (eq. 4's residual, M̂ q̈ + Ĉ q̇ + D̂ q̇ + Ĝ - A u): loss
        "accel", a physics network on (q, q̇), and a known A, without which the residual is
        smallest for a vanishing model."""
        if self.accel_space == "acceleration":
            return
        model = self.model
        if self.loss != "accel":
            raise UserError(f"accel_space: 'force' is for loss 'accel', not {self.loss!r}")
        deferred = model.kind == "hamiltonian" and self.momenta == "auto"  # resolved per file
        if model.kind not in ("lagrangian", "hamiltonian") or (
                model.state_kind != "velocity" and not deferred):
            raise UserError("accel_space: 'force' needs a lagrangian network, or a hamiltonian "
                            "one on velocities (--momenta velocity)")
        if model.input_form != "known":
            raise UserError("accel_space: 'force' needs a known input matrix (--known-input): "
                            "with A learned the force residual is smallest for a model of "
                            "vanishing M, D, G and A")

    def _check_accel_weights(self):
        """``accel_weights``: None, or n finite numbers > 0, for ``accel_space`` "force"."""
        w = self.accel_weights
        if w is None:
            return
        if isinstance(w, list):
            w = tuple(w)
            object.__setattr__(self, "accel_weights", w)
        n = self.model.n
        ok = isinstance(w, tuple) and len(w) == n and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0
            for v in w)
        if not ok:
            raise UserError(f"accel_weights: expected {n} finite numbers > 0 (one per "
                            f"coordinate), got {w!r}")
        object.__setattr__(self, "accel_weights", tuple(float(v) for v in w))
        if self.accel_space != "force":
            raise UserError("accel_weights: the weights are for accel_space 'force' (the "
                            "force residual's coordinates), not "
                            f"{self.accel_space!r}")

    def _check_momenta(self):
        """``momenta`` against the model: Hamiltonian networks only; "data" / "velocity" set
        the model's state (momentum / velocity), and a Hamiltonian model built on (q, q̇) is
        "velocity" (learn/_velocity.py; "auto" is decided for a data set by
        :func:`learn._velocity.resolve_momenta`)."""
        model = self.model
        if model.kind != "hamiltonian":
            if self.momenta != "auto":
                raise UserError(f"momenta: {self.momenta!r} is for Hamiltonian networks, not "
                                f"a {model.kind} model (leave it 'auto')")
            return
        if self.momenta == "auto":
            if model.state_kind == "velocity":
                object.__setattr__(self, "momenta", "velocity")
            return
        state = "momentum" if self.momenta == "data" else "velocity"
        if model.state_kind != state:
            object.__setattr__(self, "model", dataclasses.replace(model, state_kind=state))

    @classmethod
    def settings(cls, group: str | None = None) -> tuple[dataclasses.Field, ...]:
        """The fields that are settings (all but ``model``), of one group or all, with their
        default, ``metadata['group']``, ``metadata['help']`` and ``metadata.get('choices')``."""
        return tuple(f for f in dataclasses.fields(cls) if f.name != "model"
                     and (group is None or f.metadata["group"] == group))

    def group(self, name: str) -> dict[str, Any]:
        """The settings of one group (``optimizer``, ``loss``, ``split``, ``ensemble``,
        ``budget``) as a dict, e.g. ``config.group("optimizer")["lr"]``."""
        if name not in GROUPS:
            raise UserError(f"group: expected one of {list(GROUPS)}, got {name!r}")
        return {f.name: getattr(self, f.name) for f in self.settings(name)}

    def batch_for(self, pairs: int, devices: int = 1) -> int:
        """The minibatch size for ``pairs`` training pairs (see ``batch_size``), a multiple of
        ``devices`` (each device gets an equal share; rounded down)."""
        batch = self.batch_size if self.batch_size is not None else max(64, pairs // 100)
        batch = max(1, min(batch, pairs))
        if devices > 1:
            if batch < devices:
                raise UserError(f"devices: {devices} devices need a minibatch of at least "
                                f"{devices} pairs, got {batch}")
            batch -= batch % devices
        return batch

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["model"] = self.model.to_dict()
        if isinstance(d["test_trajectories"], tuple):
            d["test_trajectories"] = list(d["test_trajectories"])
        if isinstance(d["validation"], tuple):
            d["validation"] = list(d["validation"])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise UserError(f"unknown train config key(s) {unknown}")
        kw = dict(d)
        kw["model"] = ModelConfig.from_dict(d["model"])
        if isinstance(kw.get("test_trajectories"), list):
            kw["test_trajectories"] = tuple(kw["test_trajectories"])
        if isinstance(kw.get("validation"), list):
            kw["validation"] = tuple(kw["validation"])
        return cls(**kw)

