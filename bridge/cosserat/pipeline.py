"""``softpinn reproduce cosserat``: the networks against the simplest honest alternatives on an
arm that softpinn's own equations did not make (issue 43, item 4).

The stand-in is a Cosserat rod with a heavy tip, simulated with PyElastica (the optional extra
``cosserat``; :mod:`symbolic.standin._cosserat`): not piecewise constant curvature, actuated by
four tip moments through a dead time and a first-order lag, observed by a tip orientation
sensor at 50 Hz. For each variant, clean and with sensor noise (:data:`.settings.NOISE`, imported
with Savitzky-Golay cubics, as ``docs/experiment.md`` does):

1. **record**: the recordings as CSV files (``softpinn import``'s format) and their settings;
2. **import**: through ``softpinn import``'s library (``--model experiment --orientation
   quaternion --test-trajectories K``), keeping the observed bending coordinates (dx, dy) only;
3. **actuator**: the lag and dead time between the commands and the rod, identified on the
   training trajectories (``softpinn train --actuator identify``); every network and baseline
   below gets the same;
4. **train/<kind>**: a black box, a Lagrangian network and a Hamiltonian network trained from
   velocities, on the training trajectories, the best epoch chosen on a validation trajectory;
5. **predict/<kind>**: ``softpinn predict``'s rollout error on the held-out test trajectories at
   each horizon (1 s, 5 s);
6. **baselines**: no motion, the ARX models (order 2; lags of q and u, order chosen) and the
   linear second-order model (least squares; rollout fit), fitted on the
   same trajectories under the same actuator and scored the same way
   (:mod:`bridge.analysis.baselines`).

    OUT/
      plan.json                 every setting (recordings, variants, networks, horizons)
      <variant>/record/         cosserat_KKK.csv, cosserat.json
      <variant>/import/         data.npz (every trajectory), train.npz (train + validation)
      <variant>/train/<kind>/   the run folder (softpinn train's)
      <variant>/predict/<kind>/, <variant>/baselines/   done.json with the numbers

Every step is a stage (:class:`bridge.tasks.stages.Stages`): run again with the same settings,
finished stages are skipped. The report (``report.md``, :mod:`bridge.report.cosserat`) and
``results.json`` are written by ``softpinn.bridge.app``'s ``reproduce``.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softpinn import locks
from softpinn.bridge.analysis.baselines import BASELINES, BaselineComparison, verdict
from softpinn.bridge.base import outputs
from softpinn.bridge.cosserat.settings import NETWORKS, CosseratPlan, make_plan
from softpinn.bridge.cosserat.stages import (
    stage_actuator,
    stage_baselines,
    stage_import,
    stage_predict,
    stage_record,
    stage_train,
)
from softpinn.bridge.tasks.plan import ReproduceConfig
from softpinn.bridge.tasks.stages import Stages, write_json
from softpinn.errors import UserError
from softpinn.symbolic import COSSERAT_QUICK

MISSING_EXTRA = ("softpinn reproduce cosserat needs the optional extra: "
                 "pip install 'softpinn[cosserat]'")


@dataclass(frozen=True)
class CosseratRun:
    """A finished run (:func:`run_cosserat`): the output folder, the plan, every stage's
    result by variant (``results``) and the run's time [s]."""

    config: ReproduceConfig
    out: Path
    plan: CosseratPlan
    results: dict[str, Any] = field(repr=False)
    seconds: float
    stage_seconds: dict[str, float] = field(default_factory=dict, repr=False)


def has_pyelastica() -> bool:
    """Whether the optional extra ``cosserat`` (PyElastica, imported as ``elastica``) is
    installed."""
    return importlib.util.find_spec("elastica") is not None


def verdicts(networks: dict[str, dict], baselines: dict) -> dict[str, str]:
    """One line per network (:func:`bridge.analysis.baselines.verdict`): does it beat the best
    linear model and no motion at each horizon?"""
    comparison = BaselineComparison.from_json(baselines)
    out = {}
    for kind, label in NETWORKS:
        pred = networks.get(kind, {}).get("predict", {})
        if pred.get("missing"):
            out[kind] = f"{label}: no model to score ({pred['missing']})"
            continue
        errors = {float(h["horizon"]): (math.inf if h["mean"] is None else float(h["mean"]))
                  for h in pred["horizons"].values()}
        out[kind] = verdict(label, errors, comparison)
    return out


def run_variant(plan: CosseratPlan, variant: str, stages: Stages, progress) -> dict[str, Any]:
    """Every stage of one variant (clean or noisy)."""
    base = plan.to_dict()
    rec_settings = {k: base[k] for k in ("trajectories", "duration_s", "rate_hz", "seed", "arm")}
    rec_settings["noise"] = plan.variants[variant]["noise"]
    recorded = stages.run(f"{variant}/record", rec_settings,
                          lambda f: stage_record(plan, variant, f))
    imp_settings = {**dict(plan.variants[variant]), "record": rec_settings,
                    "test_trajectories": plan.test_trajectories,
                    "validation_trajectories": plan.validation_trajectories}
    imported = stages.run(f"{variant}/import", imp_settings,
                          lambda f: stage_import(plan, variant, recorded, f))
    act_settings = {"import": imp_settings, "actuator": plan.actuator}
    actuator = stages.run(f"{variant}/actuator", act_settings,
                          lambda f: stage_actuator(plan, imported))
    networks: dict[str, dict] = {}
    train_base = {k: base[k] for k in ("samples", "batch_size", "input_hold", "loss",
                                       "train_seed", "prior", "test_with")}
    for network in plan.networks:
        settings = {"import": imp_settings, **train_base, "actuator": act_settings,
                    "network": base["networks"][plan.networks.index(network)]}
        trained = stages.run(
            f"{variant}/train/{network.kind}", settings,
            lambda f, n=network: stage_train(plan, n, imported, actuator, f, progress))
        predicted = stages.run(f"{variant}/predict/{network.kind}",
                               {"train": settings, "horizons": list(plan.horizons)},
                               lambda f, t=trained: stage_predict(plan, imported, t, f))
        networks[network.kind] = {"train": trained, "predict": predicted}
    baselines = stages.run(f"{variant}/baselines",
                           {"import": imp_settings, "horizons": list(plan.horizons),
                            "input_hold": plan.input_hold, "actuator": act_settings,
                            "baselines": [list(b) for b in BASELINES]},
                           lambda f: stage_baselines(plan, imported, actuator))
    return {"record": recorded, "import": imported, "actuator": actuator, "networks": networks,
            "baselines": baselines, "verdicts": verdicts(networks, baselines)}


@locks.scope()  # the output's lock is given up when the call returns
def run_cosserat(config: ReproduceConfig, out_dir, *, log: Callable[[str], None],
                 progress=None, force: bool = False) -> CosseratRun:
    """Run the study into ``out_dir`` (``config.quick``: the quick form, for CI). Refused with
    one line where PyElastica is not installed (:data:`MISSING_EXTRA`)."""
    if not has_pyelastica():
        raise UserError(MISSING_EXTRA)
    plan = make_plan(config.quick, COSSERAT_QUICK)
    if config.prior is not None:
        plan = dataclasses.replace(plan, prior=config.prior)
    out = outputs.claim(out_dir, "reproduce", force=force)
    t0 = time.perf_counter()
    write_json(out / "plan.json", plan.to_dict())
    stages = Stages(out, log)
    results = {variant: run_variant(plan, variant, stages, progress)
               for variant in plan.variants}
    return CosseratRun(config, out, plan, results, time.perf_counter() - t0,
                       dict(stages.seconds))
