"""What a sweep tries: the settings it varies (a grid of values, or random draws from a range)
and the list of trials they make, each a :class:`softpinn.learn.TrainConfig` checked up front.

A setting is a field of :class:`softpinn.learn.TrainConfig` (``TrainConfig.settings()``), spelled
with ``_`` or ``-``; its values are read with the field's type. Random ranges are ``log:LOW:HIGH``
(log-uniform), ``uniform:LOW:HIGH``, ``int:LOW:HIGH`` and ``logint:LOW:HIGH`` (integers, both ends
included) and ``choice:A,B,...``. No Ray here: the trials are drawn before Ray is started, with
a seeded numpy generator, so the same command gives the same trials.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
import types
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np

from softpinn.errors import UserError
from softpinn.learn import TrainConfig

#: Kinds of random ranges: ``KIND:LOW:HIGH`` (``choice:A,B,...``).
RANDOM_KINDS = ("log", "uniform", "int", "logint", "choice")

#: Settings a sweep may not vary, and why.
NOT_SWEPT = {
    "test_trajectories": "the trials are ranked by their test loss, so they share one test split",
    "split_seed": "the trials are ranked by their test loss, so they share one test split",
    "seeds": "a trial trains one seed; give seeds=K (--seeds K) to train every combination "
             "with K seeds, one trial each",
    "accel_weights": "it is one number per coordinate; fix it for every trial "
                     "(--accel-weights W ...)",
}


def dashed(name: str) -> str:
    return name.replace("_", "-")


def _fields() -> dict[str, tuple[dataclasses.Field, type, bool]]:
    """Sweepable settings: name -> (field, value type, may be None)."""
    hints = typing.get_type_hints(TrainConfig)
    out = {}
    for f in TrainConfig.settings():
        hint = hints[f.name]
        optional = False
        if isinstance(hint, types.UnionType):
            args = typing.get_args(hint)
            optional = type(None) in args
            args = [a for a in args if a is not type(None)]
            if len(args) != 1:
                continue  # test_trajectories: ids, a count or a fraction
            hint = args[0]
        out[f.name] = (f, hint, optional)
    return out


def setting_name(text: str, label: str = "space") -> str:
    """The field a setting's name (``batch-size`` or ``batch_size``) stands for."""
    name = text.strip().replace("-", "_")
    if name in NOT_SWEPT:
        raise UserError(f"{label}: {dashed(name)} cannot be swept: {NOT_SWEPT[name]}")
    fields = _fields()
    if name not in fields:
        known = ", ".join(dashed(n) for n in fields if n not in NOT_SWEPT)
        raise UserError(f"{label}: unknown setting {text.strip()!r} (settings: {known})")
    return name


def parse_value(name: str, text: Any, label: str = "space"):
    """One value of setting ``name``, from text or a Python value, read with the field's type."""
    field, kind, optional = _fields()[name]
    where = f"{label} {dashed(name)}={text}"
    if isinstance(text, str):
        t = text.strip()
        if optional and t.lower() in ("none", "auto"):
            return None
        choices = field.metadata.get("choices")
        if kind is str:
            value = t
        else:
            try:
                value = kind(t)
            except ValueError:
                what = "an integer" if kind is int else "a number"
                if optional:
                    what += " or 'none'"
                raise UserError(f"{where}: expected {what}") from None
    else:
        value = text
        if value is None and optional:
            return None
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise UserError(f"{where}: expected a value of type {kind.__name__}")
        choices = field.metadata.get("choices")
    if choices and value not in choices:
        raise UserError(f"{where}: expected one of {', '.join(choices)}")
    if kind is float and not math.isfinite(value):
        raise UserError(f"{where}: expected a finite number")
    return value


@dataclass(frozen=True)
class Random:
    """A random range of one setting: ``kind`` in :data:`RANDOM_KINDS`; ``low``, ``high`` (both
    included for the integer kinds) or ``choices``."""

    kind: str
    low: float | int | None = None
    high: float | int | None = None
    choices: tuple = ()

    def draw(self, rng: np.random.Generator):
        if self.kind == "choice":
            return self.choices[int(rng.integers(len(self.choices)))]
        if self.kind == "uniform":
            return float(rng.uniform(self.low, self.high))
        if self.kind == "log":
            return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))
        if self.kind == "int":
            return int(rng.integers(self.low, self.high + 1))
        # logint: log-uniform over [low, high + 1), rounded down
        x = math.exp(rng.uniform(math.log(self.low), math.log(self.high + 1)))
        return int(min(self.high, math.floor(x)))

    def describe(self) -> str:
        if self.kind == "choice":
            return "choice:" + ",".join(str(c) for c in self.choices)
        return f"{self.kind}:{self.low:g}:{self.high:g}"


def parse_random(name: str, text: str, label: str = "random") -> Random:
    """``log:1e-4:1e-2``, ``uniform:0:0.1``, ``int:1:4``, ``logint:16:256``, ``choice:a,b``."""
    field, kind, optional = _fields()[name]
    where = f"{label} {dashed(name)}={text}"
    head, sep, rest = text.partition(":")
    if not sep or head not in RANDOM_KINDS:
        raise UserError(f"{where}: expected KIND:LOW:HIGH or choice:A,B,... with KIND one of "
                        f"{', '.join(k for k in RANDOM_KINDS if k != 'choice')}")
    if head == "choice":
        values = [v for v in rest.split(",") if v.strip()]
        if not values:
            raise UserError(f"{where}: expected choice:A,B,...")
        return Random("choice", choices=tuple(parse_value(name, v, label) for v in values))
    if kind is str:
        raise UserError(f"{where}: {dashed(name)} takes choice:A,B,... "
                        f"(one of {', '.join(field.metadata.get('choices') or ())})")
    if head in ("int", "logint") and kind is not int:
        raise UserError(f"{where}: {dashed(name)} is a number; use log: or uniform:")
    if head in ("log", "uniform") and kind is int:
        raise UserError(f"{where}: {dashed(name)} is an integer; use int: or logint:")
    parts = rest.split(":")
    if len(parts) != 2:
        raise UserError(f"{where}: expected {head}:LOW:HIGH")
    low, high = (parse_value(name, p, label) for p in parts)
    if low is None or high is None or not low < high:
        raise UserError(f"{where}: expected LOW < HIGH")
    if head in ("log", "logint") and low <= 0:
        raise UserError(f"{where}: a log range needs LOW > 0")
    return Random(head, low, high)


def parse_assignment(text: str, label: str) -> tuple[str, str]:
    """``name=values`` of ``--grid`` / ``--random``: (field name, values text)."""
    name, sep, values = text.partition("=")
    if not sep or not name.strip() or not values.strip():
        raise UserError(f"{label} {text}: expected SETTING=VALUES, e.g. lr=1e-3,3e-3")
    return setting_name(name, label), values.strip()


def parse_space(grid: list[str] = (), random: list[str] = ()) -> dict[str, list | Random]:
    """The space of the command line's ``--grid NAME=V1,V2,...`` and ``--random NAME=RANGE``."""
    space: dict[str, list | Random] = {}
    for label, items in (("--grid", grid), ("--random", random)):
        for text in items:
            name, values = parse_assignment(text, label)
            if name in space:
                raise UserError(f"{label} {text}: {dashed(name)} is given twice")
            if label == "--grid":
                space[name] = [parse_value(name, v, label) for v in values.split(",")
                               if v.strip()]
            else:
                space[name] = parse_random(name, values, label)
    return space


def check_space(space: dict) -> dict[str, list | Random]:
    """``space`` with its names resolved and its values typed: a list (tuple) of values for a
    grid, a :class:`Random` or its text (``"log:1e-4:1e-2"``) for random draws."""
    if not isinstance(space, dict):
        raise UserError(f"space: expected a dict of setting -> values, got {type(space).__name__}")
    out: dict[str, list | Random] = {}
    for key, values in space.items():
        name = setting_name(str(key))
        if name in out:
            raise UserError(f"space: {dashed(name)} is given twice")
        if isinstance(values, Random):
            out[name] = values
        elif isinstance(values, str):
            out[name] = parse_random(name, values, "space")
        elif isinstance(values, (list, tuple)):
            if not values:
                raise UserError(f"space: {dashed(name)}: no values")
            out[name] = [parse_value(name, v, "space") for v in values]
        else:
            raise UserError(f"space: {dashed(name)}: expected a list of values (a grid) or a "
                            f"random range such as 'log:1e-4:1e-2', got {values!r}")
    return out


def format_value(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


@dataclass(frozen=True)
class Trial:
    """One trial: its folder name, the values of the swept settings, its seed and config."""

    name: str
    settings: dict
    seed: int
    config: TrainConfig


def _name(index: int, settings: dict, seed: int, with_seed: bool) -> str:
    parts = [f"{index:03d}"] + [f"{dashed(k)}={format_value(v)}" for k, v in settings.items()]
    if with_seed:
        parts.append(f"seed={seed}")
    name = re.sub(r"[^A-Za-z0-9_.=+-]", "_", "_".join(parts))
    return name[:120]


def make_trials(base: TrainConfig, space: dict, *, samples: int = 1, seeds: int = 1,
                random_seed: int = 0) -> list[Trial]:
    """Every trial: for each of ``samples`` draws of the random settings, every combination of
    the grid, each with ``seeds`` seeds (``base.seed``, ``base.seed + 1``, ...), in that order.
    Every config is built here, so a value the settings refuse is one error before any run."""
    for name, v, low in (("samples", samples, 1), ("seeds", seeds, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise UserError(f"{name}: expected an integer >= {low}, got {v!r}")
    if base.seeds != 1:
        raise UserError(f"seeds: {NOT_SWEPT['seeds']} (the base config has seeds={base.seeds})")
    space = check_space(space)
    grid = {k: v for k, v in space.items() if not isinstance(v, Random)}
    random = {k: v for k, v in space.items() if isinstance(v, Random)}
    if samples > 1 and not random:
        raise UserError("samples: random draws need a random range (--random SETTING=RANGE); "
                        "a grid alone gives the same trials every time")
    if "seed" in space and seeds > 1:
        raise UserError("seed: give seeds=K (--seeds K) or sweep seed, not both")
    rng = np.random.default_rng(random_seed)
    trials: list[Trial] = []
    for _ in range(samples):
        drawn = {k: r.draw(rng) for k, r in random.items()}
        for combo in itertools.product(*grid.values()):
            settings = {**dict(zip(grid, combo, strict=True)), **drawn}
            settings = {k: settings[k] for k in space}  # in the order given
            for j in range(seeds):
                seed = settings.get("seed", base.seed + j)
                try:
                    config = dataclasses.replace(base, **{**settings, "seed": seed})
                except UserError as exc:
                    values = ", ".join(f"{dashed(k)}={format_value(v)}"
                                       for k, v in settings.items())
                    raise UserError(f"trial {values}: {exc}") from None
                trials.append(Trial(_name(len(trials), settings, seed, seeds > 1),
                                    settings, seed, config))
    return trials
