"""Physics-inspired networks (JAX, Equinox, optax): Lagrangian, Hamiltonian and black-box
dynamics models, one-step Runge-Kutta losses, training and prediction. Never imports casadi.

Core API::

    from softpinn.learn import ModelConfig, TrainConfig, train, load_run, predict
    config = TrainConfig(ModelConfig(kind="lagrangian", n=2, m=0), epochs=300)
    result = train("data.npz", config, "runs/lnn")       # writes config.json, model.eqx, ...
    run = load_run("runs/lnn"); run.model.matrices(q)     # learned M, D, G, A at q
    predict("runs/lnn", "data.npz", horizon=2.7)          # one-step and rollout errors
"""

from softpinn.learn._config import TrainConfig
from softpinn.learn._data import load_dataset
from softpinn.errors import UserError
from softpinn.learn._integrate import rk4_step, rollout, step
from softpinn.learn._losses import Pairs, accel_loss, pair_errors, pair_loss, rollout_loss
from softpinn.learn._models import DynamicsModel, ModelConfig, make_model
from softpinn.learn._predict import evaluate, predict
from softpinn.learn._programs import ProgramCache
from softpinn.learn._rundir import LoadedRun, load_ensemble, load_run
from softpinn.learn._train import TrainingDiverged, TrainResult, train

__all__ = [
    "DynamicsModel",
    "ModelConfig",
    "LoadedRun",
    "Pairs",
    "ProgramCache",
    "TrainConfig",
    "TrainResult",
    "TrainingDiverged",
    "UserError",
    "accel_loss",
    "evaluate",
    "load_dataset",
    "load_ensemble",
    "load_run",
    "make_model",
    "pair_errors",
    "pair_loss",
    "predict",
    "rk4_step",
    "rollout",
    "rollout_loss",
    "step",
    "train",
]
