"""Physics-inspired networks (JAX, Equinox, optax): Lagrangian, Hamiltonian and black-box
dynamics models, one-step Runge-Kutta losses, training and prediction. Never imports casadi.

Core API::

    from softpinn.learn import ModelConfig, TrainConfig, train, load_run, predict
    config = TrainConfig(ModelConfig(kind="lagrangian", n=2, m=0), epochs=300)
    result = train("data.npz", config, "runs/lnn")       # writes config.json, model.eqx, ...
    run = load_run("runs/lnn"); run.model.matrices(q)     # learned M, D, G, A at q
    predict("runs/lnn", "data.npz", horizon=2.7)          # one-step and rollout errors
"""

from __future__ import annotations

from softpinn.errors import NonFiniteStart, TrainingDiverged, UserError
from softpinn.learn._actuator import (
    identify_actuator,
    resolve_actuator,
    run_actuator,
    with_actuator,
)
from softpinn.learn._advice import recording_defaults
from softpinn.learn._baseline_errors import BaselineErrors, range_box
from softpinn.learn._baseline_errors import rollout_errors as baseline_rollout_errors
from softpinn.learn._baseline_kinds import BASELINE_KINDS, baseline_from_dict, fit_baseline
from softpinn.learn._baselines import (
    ARX,
    LinearSecondOrder,
    NoMotion,
    fit_arx,
    fit_linear_second_order,
)
from softpinn.learn._checkpoint import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    check_run_dir,
    read_history,
    read_json,
)
from softpinn.learn._config import GROUPS, RESUMABLE, TrainConfig
from softpinn.learn._data import (
    Dataset,
    file_sha256,
    load_dataset,
    make_pairs,
    mass_scale,
    trajectories,
)
from softpinn.learn._devices import resolve_devices
from softpinn.learn._integrate import rk4_step, rollout, step
from softpinn.learn._known_input import known_input_text, parse_known_input
from softpinn.learn._losses import (
    Equilibria,
    Pairs,
    accel_loss,
    data_force_weights,
    equilibrium_forces,
    pair_errors,
    pair_loss,
    rollout_loss,
)
from softpinn.learn._models import DynamicsModel, ModelConfig, make_model
from softpinn.learn._output_error import LinearRolloutFit, fit_linear_rollout
from softpinn.learn._predict import evaluate, one_step_errors, predict, rollouts
from softpinn.learn._prior import PRIOR_SETTINGS, resolve_prior
from softpinn.learn._programs import ProgramCache
from softpinn.learn._rundir import LoadedRun, dataset_info, load_ensemble, load_run
from softpinn.learn._splits import recorded_test_split, split_trajectories
from softpinn.learn._steptime import time_train_steps
from softpinn.learn._stop import Stop, StopReason
from softpinn.learn._sx_replay import KNOWN_OPS, PROGRAM_FORMAT, replay
from softpinn.learn._train import TrainResult, train
from softpinn.learn._velocity import resolve_momenta

__all__ = [
    "accel_loss",
    "ARX",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "BASELINE_KINDS",
    "baseline_from_dict",
    "BaselineErrors",
    "check_run_dir",
    "data_force_weights",
    "Dataset",
    "dataset_info",
    "DynamicsModel",
    "Equilibria",
    "equilibrium_forces",
    "evaluate",
    "file_sha256",
    "fit_arx",
    "fit_baseline",
    "fit_linear_rollout",
    "fit_linear_second_order",
    "GROUPS",
    "known_input_text",
    "KNOWN_OPS",
    "load_dataset",
    "load_ensemble",
    "load_run",
    "LinearRolloutFit",
    "LinearSecondOrder",
    "LoadedRun",
    "make_model",
    "PRIOR_SETTINGS",
    "resolve_prior",
    "make_pairs",
    "mass_scale",
    "ModelConfig",
    "NoMotion",
    "NonFiniteStart",
    "one_step_errors",
    "pair_errors",
    "pair_loss",
    "Pairs",
    "parse_known_input",
    "predict",
    "PROGRAM_FORMAT",
    "ProgramCache",
    "read_history",
    "read_json",
    "recorded_test_split",
    "replay",
    "resolve_devices",
    "resolve_momenta",
    "RESUMABLE",
    "rk4_step",
    "range_box",
    "identify_actuator",
    "recording_defaults",
    "resolve_actuator",
    "run_actuator",
    "with_actuator",
    "rollout",
    "baseline_rollout_errors",
    "rollout_loss",
    "rollouts",
    "split_trajectories",
    "step",
    "Stop",
    "StopReason",
    "time_train_steps",
    "train",
    "TrainConfig",
    "TrainingDiverged",
    "TrainResult",
    "trajectories",
    "UserError",
]
