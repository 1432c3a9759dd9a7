"""The task recipe: a spec's ``[training]`` table, typed and validated (``docs/recipes.md``).

A recipe says which networks to train on the spec's data and how: the paper's network sizes and
epochs (Table III), our budgets for full runs, the quick settings, how every model integrates a
data step, and what to report. ``softpinn reproduce`` reads nothing else, so a user writes a
recipe for their own robot in the same TOML.

The table is validated like every other table of the spec when the spec is loaded: an unknown
key, a wrong type or a bad value is refused with an error naming the file and the field. The
keys of ``[training.full.<network>]`` are ``softpinn.learn`` training settings (the flat names of
``TrainConfig``); a bridge test checks that every one exists there, so no setting gets a second
default here: a key left out takes ``TrainConfig``'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

PHYSICS = ("lagrangian", "hamiltonian")
NETWORKS = (*PHYSICS, "blackbox")

#: [training.<network>]: the paper's network (Table III: sizes as [width, depth], its epochs)
#: and what the network learns from in every run (its loss), as learn's TrainConfig names them
NETWORK_KEYS = {
    "lagrangian": ("mass", "potential", "damping", "input", "epochs"),
    "hamiltonian": ("mass", "potential", "damping", "input", "epochs"),
    "blackbox": ("hidden", "epochs"),
}
LOSS_KEYS: dict[str, tuple[str, tuple | None]] = {
    "loss": ("str", ("pair", "accel", "rollout")),
    "loss_weight": ("float", None),
    "accel_labels": ("str", ("recorded", "differences")),
    "accel_space": ("str", ("acceleration", "force")),
    "test_with": ("str", ("loss", "pair")),
}

#: [training.<physics network>]: what the network is built with and how it takes the data, in
#: every run: ``damping_form`` and ``momenta`` as learn's ModelConfig / TrainConfig name them;
#: ``known_input = true`` fixes A(q) to this spec's own (the known actuator model of Section
#: VI-B); ``momenta`` is a Hamiltonian network's alone
MODEL_KEYS: dict[str, tuple[str, tuple | None]] = {
    "damping_form": ("str", ("network", "constant", "none")),
    "known_input": ("bool", None),
    "momenta": ("str", ("auto", "data", "velocity")),
}

#: [training.<network>]: how the network steps a data interval, in every run: ``max_step`` [s]
#: overrides [training]'s for this network (its sub-steps: ceil(data step / max_step))
STEP_KEYS: dict[str, tuple[str, tuple | None]] = {
    "max_step": ("float", None),
}

#: [training.full.<network>]: our budget for full runs -> (kind, allowed values)
BUDGET_KEYS: dict[str, tuple[str, tuple | None]] = {
    "epochs": ("int", None),
    "lbfgs_steps": ("int0", None),
    "lr": ("float", None),
    "equal_steps": ("bool", None),
    "patience": ("int", None),
    "overfit": ("ratio", None),
    "test_samples": ("int", None),
}

#: [training.quick]: the quick settings (``reproduce --quick``): data and budget
QUICK_KEYS: dict[str, str] = {
    "duration": "float",
    "epochs": "int",
    "rates": "floats",
    "fixed_step_duration": "float",
    "fixed_step_rate": "float",
    "fixed_step_trajectories": "int",
    "fixed_step_train_trajectories": "int",
}

#: [training] itself
TOP_KEYS: dict[str, str] = {
    "physics": "physics",
    "prediction_horizon": "float",
    "matrix_q": "rows",
    "batch_size": "int",
    "substeps": "int",
    "input_hold": "hold",
    "max_step": "float",
    "other_dt": "float",
    "blackbox_rates": "floats",
}

#: defaults of the quick settings (a recipe's [training.quick] overrides them)
QUICK_DEFAULTS = MappingProxyType({"duration": 4.0, "epochs": 300})


class RecipeError(ValueError):
    """Raised with (field, message); :mod:`symbolic.spec._spec` turns it into a SpecError."""

    def __init__(self, where: str, message: str):
        super().__init__(f"field '{where}': {message}")
        self.where, self.message = where, message


@dataclass(frozen=True)
class Recipe:
    """A validated ``[training]`` table. ``networks[kind]`` holds the paper's sizes and epochs
    and the network's loss settings, ``full[kind]`` our full-run budget (training settings by
    their ``TrainConfig`` names), ``quick`` the quick settings."""

    physics: tuple[str, ...] = ("lagrangian",)
    prediction_horizon: float = 5.0
    matrix_q: tuple[tuple[float, ...], ...] = ()
    batch_size: int = 64
    substeps: int = 1
    input_hold: str = "constant"
    max_step: float | None = None
    other_dt: float | None = None
    blackbox_rates: tuple[float, ...] | None = None
    networks: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    full: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    quick: Mapping[str, Any] = field(default_factory=lambda: dict(QUICK_DEFAULTS))

    def network(self, kind: str, key: str, default=None):
        """The paper's setting ``key`` of network ``kind`` (Table III), or ``default``."""
        return self.networks.get(kind, {}).get(key, default)


def parse_recipe(raw: Mapping[str, Any], n: int) -> Recipe:
    """Validate a ``[training]`` table of a spec with n coordinates; raise :class:`RecipeError`."""
    raw = dict(raw)
    allowed = set(TOP_KEYS) | set(NETWORKS) | {"full", "quick"}
    _no_unknown(raw, allowed, "training.")
    top: dict[str, Any] = {}
    for key, kind in TOP_KEYS.items():
        if key in raw:
            top[key] = _value(raw[key], kind, f"training.{key}", n)
    networks = {}
    for kind in NETWORKS:
        if kind in raw:
            table = _table(raw[kind], f"training.{kind}")
            model_keys = ({k for k in MODEL_KEYS if k != "momenta" or kind == "hamiltonian"}
                          if kind in PHYSICS else set())
            _no_unknown(table, set(NETWORK_KEYS[kind]) | set(LOSS_KEYS) | set(STEP_KEYS)
                        | model_keys, f"training.{kind}.")
            net = {}
            for k, v in table.items():
                if k in LOSS_KEYS:
                    net[k] = _choice(v, *LOSS_KEYS[k], f"training.{kind}.{k}", n)
                elif k in STEP_KEYS:
                    net[k] = _choice(v, *STEP_KEYS[k], f"training.{kind}.{k}", n)
                elif k in MODEL_KEYS:
                    net[k] = _choice(v, *MODEL_KEYS[k], f"training.{kind}.{k}", n)
                else:
                    net[k] = _value(v, "int" if k == "epochs" else "size",
                                    f"training.{kind}.{k}", n)
            networks[kind] = MappingProxyType(net)
    full = {}
    if "full" in raw:
        fulls = _table(raw["full"], "training.full")
        _no_unknown(fulls, set(NETWORKS), "training.full.")
        for kind, table in fulls.items():
            table = _table(table, f"training.full.{kind}")
            _no_unknown(table, set(BUDGET_KEYS), f"training.full.{kind}.")
            full[kind] = MappingProxyType({
                k: _choice(v, *BUDGET_KEYS[k], f"training.full.{kind}.{k}", n)
                for k, v in table.items()})
    quick = dict(QUICK_DEFAULTS)
    if "quick" in raw:
        table = _table(raw["quick"], "training.quick")
        _no_unknown(table, set(QUICK_KEYS), "training.quick.")
        quick.update({k: _value(v, QUICK_KEYS[k], f"training.quick.{k}", n)
                      for k, v in table.items()})
    return Recipe(**top, networks=MappingProxyType(networks), full=MappingProxyType(full),
                  quick=MappingProxyType(quick))


def _choice(value, kind: str, choices: tuple | None, where: str, n: int):
    out = _value(value, kind, where, n)
    if choices and out not in choices:
        raise RecipeError(where, f"expected one of {', '.join(choices)}, got {value!r}")
    return out


def _no_unknown(table: Mapping[str, Any], allowed: set[str], prefix: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise RecipeError(f"{prefix}{unknown[0]}",
                          f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _table(value, where: str) -> dict:
    if not isinstance(value, Mapping):
        raise RecipeError(where, f"expected a table, got {value!r}")
    return dict(value)


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RecipeError(where, f"expected a number, got {value!r}")
    if not math.isfinite(value):
        raise RecipeError(where, f"must be finite, got {value}")
    return float(value)


def _value(value, kind: str, where: str, n: int):
    if kind in ("int", "int0"):
        if isinstance(value, bool) or not isinstance(value, int):
            raise RecipeError(where, f"expected an integer, got {value!r}")
        least = 0 if kind == "int0" else 1
        if value < least:
            raise RecipeError(where, f"must be at least {least}, got {value}")
        return int(value)
    if kind == "float":
        x = _number(value, where)
        if not x > 0:
            raise RecipeError(where, f"must be positive, got {value}")
        return x
    if kind == "ratio":  # a factor over a best value
        x = _number(value, where)
        if not x > 1:
            raise RecipeError(where, f"must be greater than 1, got {value}")
        return x
    if kind == "bool":
        if not isinstance(value, bool):
            raise RecipeError(where, f"expected true or false, got {value!r}")
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise RecipeError(where, f"expected a string, got {value!r}")
        return value
    if kind == "hold":
        if value not in ("constant", "linear"):
            raise RecipeError(where, f"expected one of constant, linear, got {value!r}")
        return value
    if kind == "physics":
        if (not isinstance(value, Sequence) or isinstance(value, str) or not value
                or any(v not in PHYSICS for v in value)):
            raise RecipeError(where, f"expected a list of {' / '.join(PHYSICS)}, got {value!r}")
        return tuple(value)
    if kind == "floats":
        if not isinstance(value, Sequence) or isinstance(value, str) or not value:
            raise RecipeError(where, f"expected a list of numbers, got {value!r}")
        return tuple(_value(v, "float", f"{where}[{i}]", n) for i, v in enumerate(value))
    if kind == "size":
        if (not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 2
                or any(isinstance(v, bool) or not isinstance(v, int) or v < 1 for v in value)):
            raise RecipeError(where, f"expected [width, depth] (integers >= 1), got {value!r}")
        return (int(value[0]), int(value[1]))
    if kind == "rows":
        if not isinstance(value, Sequence) or isinstance(value, str):
            raise RecipeError(where, f"expected a list of rows of {n} numbers, got {value!r}")
        rows = []
        for i, row in enumerate(value):
            if not isinstance(row, Sequence) or isinstance(row, str) or len(row) != n:
                raise RecipeError(f"{where}[{i}]", f"expected {n} numbers, got {row!r}")
            rows.append(tuple(_number(x, f"{where}[{i}]") for x in row))
        return tuple(rows)
    raise AssertionError(kind)
