"""Physics-inspired networks (JAX, Equinox, optax): Lagrangian, Hamiltonian and black-box
dynamics models, one-step Runge-Kutta losses, training and prediction. Never imports casadi.

Core API::

    from softpinn.learn import ModelConfig, TrainConfig, train, load_run, predict
    config = TrainConfig(ModelConfig(kind="lagrangian", n=2, m=0), epochs=300)
    result = train("data.npz", config, "runs/lnn")       # writes config.json, model.eqx, ...
    run = load_run("runs/lnn"); run.model.matrices(q)     # learned M, D, G, A at q
    predict("runs/lnn", "data.npz", horizon=2.7)          # one-step and rollout errors
"""

from .config import TrainConfig
from .data import load_dataset
from .errors import UserError
from .integrate import rk4_step, rollout, step
from .losses import Pairs, accel_loss, pair_errors, pair_loss, rollout_loss
from .models import DynamicsModel, ModelConfig, make_model
from .predict import evaluate, predict
from .programs import ProgramCache
from .rundir import LoadedRun, load_ensemble, load_run
from .train import TrainingDiverged, TrainResult, train

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
