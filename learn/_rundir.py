"""The run directory (``docs/rundir.md``): where a run's members live, its aggregate
metrics, history and loss plot, and loading a finished run back (:func:`load_run`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._actuator import run_actuator, with_actuator
from softpinn.learn._config import FORMAT, TrainConfig
from softpinn.learn._data import (
    Dataset,
)
from softpinn.learn._models import ModelConfig, ensure_dtype, make_model
from softpinn.learn.plots import plot_loss_curves

# ------------------------------------------------------------------------------ run layout


def dataset_info(data: Dataset) -> dict:
    return {
        "path": data.path,
        "sha256": data.sha256,
        "n": data.n,
        "m": data.m,
        "name": data.meta.get("spec", {}).get("name") if isinstance(data.meta, dict) else None,
    }


def member_dir(run_dir: Path, seed: int, k_total: int) -> Path:
    return run_dir if k_total == 1 else run_dir / f"{ckpt.MEMBER_PREFIX}{seed}"


def mean_std(values) -> dict:
    v = np.asarray(values, dtype=float)
    return {"mean": float(v.mean()), "std": float(v.std())}


def loss_plot(run_dir, histories, labels):
    plot_loss_curves(histories, run_dir / "loss.png", labels=labels, title=_plot_title(run_dir),
                     record=True)


def _plot_title(run_dir: Path) -> str:
    """What a run's loss plot is of: the model kind, the data set and the member, from the
    run's config.json (the folder's name alone was 'run' for every task stage)."""
    try:
        info = json.loads((Path(run_dir) / "config.json").read_text())
        kind = info["model"]["kind"]
        data = info.get("dataset", {})
        name = data.get("name") or Path(str(data.get("path", ""))).stem or "data"
    except (OSError, ValueError, KeyError, TypeError):
        return f"{Path(run_dir).name}: loss (train solid, test dashed)"
    seed = f", seed {info['seed']}" if "seed" in info else ""
    train = info.get("train", {})
    if train.get("test_with") == "pair" and train.get("loss") != "pair":
        return (f"{kind} network on {name}{seed}: training loss ({train.get('loss')}, solid), "
                "test: one-step error (eq. 8/9, dashed)")
    if train.get("test_with") == "rollout":
        return (f"{kind} network on {name}{seed}: training loss ({train.get('loss')}, solid), "
                f"held out: rollout error over {train.get('test_steps')} steps (dashed)")
    return f"{kind} network on {name}{seed}: loss (train solid, test dashed)"



def mean_history(histories):
    by_epoch: dict[int, list[dict]] = {}
    for h in histories:
        for r in h:
            by_epoch.setdefault(r["epoch"], []).append(r)
    rows = []
    for e in sorted(by_epoch):
        rs = by_epoch[e]
        rows.append(
            {
                "epoch": e,
                "train_loss": float(np.mean([r["train_loss"] for r in rs])),
                "test_loss": float(np.mean([r["test_loss"] for r in rs])),
                **({"validation_loss": float(np.mean([r["validation_loss"] for r in rs]))}
                   if all("validation_loss" in r for r in rs) else {}),
                "seconds": max(r["seconds"] for r in rs),
                "phase": rs[0]["phase"],
            }
        )
    return rows


def aggregate_metrics(members, mode, base) -> dict:
    """Mean ± std over the members; the best member is the one of the lowest best validation
    loss where the run held out validation trajectories (the test loss never picks), else of
    the lowest best test loss."""
    best = [m.metrics["best_test_loss"] for m in members]
    val = [m.metrics["best_validation_loss"] for m in members
           if "best_validation_loss" in m.metrics]
    picks = val if len(val) == len(members) else best
    return {
        "seeds": [m.seed for m in members],
        "ensemble_mode": mode,
        "best_test_loss": mean_std(best),
        **({"best_validation_loss": mean_std(val)} if picks is val else {}),
        "final_train_loss": mean_std([m.metrics["final_train_loss"] for m in members]),
        "seconds": mean_std([m.metrics["seconds"] for m in members]),
        "best_member": members[int(np.argmin(picks))].seed,
        "pairs": base["pairs"],
        "train_pairs": base["pairs"]["train"],
        "test_pairs": base["pairs"]["test"],
        "members": [m.metrics for m in members],
    }



# --------------------------------------------------------------------------------- loading


@dataclass
class LoadedRun:
    """A trained model read back from a run directory."""

    model: Any
    model_config: ModelConfig
    train_config: TrainConfig
    seed: int
    run_dir: Path
    info: dict  # the whole config.json (dataset path/hash, split, pairs, ...)

    def inputs(self, data: Dataset) -> Dataset:
        """``data`` as the model sees it: u through the run's actuator (learn/_actuator.py;
        none for a run without one)."""
        return with_actuator(data, run_actuator(self.train_config.actuator, data.m))


def load_run(run_dir: str | Path, *, member: int | None = None) -> LoadedRun:
    """Load the best model of a run directory (``model.eqx`` + ``config.json``).

    For an ensemble directory, ``member`` picks the seed; None picks the member with the lowest
    best test loss (from ``metrics.json``). A member folder ``RUN/seed-<s>`` loads directly;
    a single run refuses a ``member`` other than its seed. The model file's checksum is
    verified, and its parameters must be finite.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise UserError(f"run directory {run_dir}: no such directory")
    info = ckpt.read_json(run_dir / "config.json")
    model = info.get("model") if isinstance(info, dict) else None
    if isinstance(model, dict) and model.get("kind") == "linear":  # train --model linear
        raise UserError(f"run {run_dir}: a linear baseline run has no learned matrices; "
                        "'softpinn predict' scores it (train a network to analyze or export)")
    if info.get("format") != FORMAT:
        raise UserError(f"{run_dir}/config.json: not a softpinn run directory")
    if "members" in info:
        seeds = info["seeds"]
        if member is None:
            mpath = run_dir / "metrics.json"
            if mpath.is_file():
                member = ckpt.read_json(mpath)["best_member"]
            else:
                member = seeds[0]
        if member not in seeds:
            raise UserError(f"run {run_dir}: no member with seed {member} (seeds {seeds})")
        return load_run(run_dir / f"{ckpt.MEMBER_PREFIX}{member}")
    if member is not None and member != info.get("seed"):
        raise UserError(
            f"member: run {run_dir} has one member (seed {info.get('seed')}), not seed {member}"
        )
    mcfg = ModelConfig.from_dict(info["model"])
    tcfg = TrainConfig.from_dict(info["train"])
    ensure_dtype(mcfg.dtype)
    # the model's structure by shape alone: no initialisation runs (each of its random draws
    # and small ops compiled on its own, seconds per load)
    skeleton = eqx.filter_eval_shape(make_model, mcfg, key=jax.random.PRNGKey(0))
    like, static = eqx.partition(skeleton, lambda x: isinstance(x, jax.ShapeDtypeStruct))
    path = run_dir / "model.eqx"
    if not path.is_file():
        raise UserError(f"run {run_dir}: no model.eqx yet (training not finished; --resume it)")
    _, params = ckpt.load_tree(path, like)
    if not all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(params)):
        raise UserError(f"{path}: the model's parameters are not all finite (NaN or inf)")
    return LoadedRun(
        model=eqx.combine(params, static),
        model_config=mcfg,
        train_config=tcfg,
        seed=int(info["seed"]),
        run_dir=run_dir,
        info=info,
    )


def load_ensemble(run_dir: str | Path) -> list[LoadedRun]:
    """All members of a run directory (a single run gives a list of one)."""
    run_dir = Path(run_dir)
    info = ckpt.read_json(run_dir / "config.json")
    if "members" not in info:
        return [load_run(run_dir)]
    return [load_run(run_dir, member=s) for s in info["seeds"]]
