"""The stages of ``softpinn reproduce experiment`` (:mod:`.experiment`): simulate, record with the
spec's sensor, import with one preprocessing, train, predict, score the baselines at the same
horizons, compare the bending matrices. Each takes the run's :class:`.experiment.ExperimentPlan`
and writes into its own folder. With the plan's actuator (``--actuator``) the networks train and
predict on its output (``TrainConfig.actuator``, the run applies it) and the baselines are fitted
and scored on the same inputs (:func:`softpinn.learn.with_actuator`)."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from softpinn.bridge.analysis import learned_matrices, true_matrices
from softpinn.bridge.analysis.baselines import BASELINES, fit_baselines, score_models
from softpinn.bridge.analysis.matrices import MatrixStack
from softpinn.bridge.analysis.transforms import fit_transform
from softpinn.learn import (
    ModelConfig,
    Pairs,
    TrainConfig,
    evaluate,
    load_dataset,
    load_ensemble,
    make_pairs,
    one_step_errors,
    train,
    trajectories,
    with_actuator,
)
from softpinn.symbolic import (
    SensorConfig,
    TrueModel,
    import_recordings,
    make_dataset,
    parse_smoother,
    read_dataset,
    record,
    write_csv,
    write_dataset,
)


def rate_name(rate: float) -> str:
    return f"{rate:g}Hz"


def stage_simulate(spec, plan, folder: Path) -> dict:

    data = make_dataset(spec, data=dict(plan.data), integrator="cvodes", rate=plan.sim_rate)
    path = write_dataset(folder / "simulated.npz", data, force=True)
    q = data.q
    theta = np.hypot(q[:, 0], q[:, 1]) / spec.segments[0].actuator_radius
    return {"path": str(path), "samples": len(data.t), "rate": plan.sim_rate,
            "trajectories": int(data.meta["trajectories"]),
            "theta_max": float(theta.max()), "theta_rms": float(np.sqrt(np.mean(theta**2))),
            "dL_range": [float(q[:, 2].min()), float(q[:, 2].max())],
            "timings_s": data.meta.get("timings_s", {})}


def stage_record(spec, plan, rate: float, simulated: dict, folder: Path) -> dict:

    sim = read_dataset(simulated["path"])
    raw = dict(plan.sensor)
    sensor = SensorConfig(rate_hz=rate, kind=raw["kind"], noise_std=tuple(raw["noise_std"]),
                          bias_walk_std=tuple(raw["bias_walk_std"]), output=raw["output"],
                          seed=int(raw["seed"]))
    rec = record(spec, sensor, sim.t, sim.q, sim.qd, sim.u, sim.traj, qdd=sim.qdd)
    csv_path = write_csv(folder / "imu.csv", rec, comment=(
        f"Simulated IMU on the tip of the softpinn 'experiment' arm (a stand-in for the paper's "
        f"unpublished recordings): {sensor.rate_hz:g} Hz, white noise {list(sensor.noise_std)} "
        f"rad, bias random walk {list(sensor.bias_walk_std)} rad/sqrt(s), seed {sensor.seed}. "
        "Import: softpinn import imu.csv --model experiment --orientation "
        f"{'rpy' if sensor.output == 'rpy' else 'quaternion'}" + _actuator_comment(plan, spec.m)))
    truth = folder / "truth.npz"
    np.savez(truth, t=rec.t, traj=rec.traj, q=rec.q_true, qd=rec.qd_true,
             angles_true=rec.angles_true, angles=rec.angles, bias=rec.bias)
    noise = rec.angles - rec.angles_true - rec.bias
    return {"csv": str(csv_path), "truth": str(truth), "samples": len(rec.t),
            "sensor": sensor.to_dict(),
            "noise_rms": np.sqrt(np.mean(noise**2, axis=0)).tolist(),
            "bias_rms": np.sqrt(np.mean(rec.bias**2, axis=0)).tolist(),
            "bias_max": np.max(np.abs(rec.bias), axis=0).tolist()}


def _actuator_comment(plan, m: int) -> str:
    """The recording's note on the actuator (none: nothing, as before the option existed)."""
    if not plan.actuator:
        return ""
    act = plan.actuator_dynamics(m)
    return (f". u holds the commands; they reach the arm through a {act.describe()} "
            f"(train with --actuator {act.text()})")


def bending_only(data, spec):
    """The bending part (dx, dy) of an imported data set: what the IMU observes. The stretch
    dL, set to 0 by the import because orientation cannot see it, is left out, so the networks
    learn the bending model (p keeps M_bb q̇_b, as q̇_L = 0)."""
    keep = slice(0, 2)
    names = list(spec.coordinate_names[:2])
    meta = {**data.meta, "n": 2, "coordinates": names,
            "bending_only": f"the bending coordinates {', '.join(names)} of the imported data; "
                            f"{spec.coordinate_names[2]} (not observable, set to 0 by the "
                            "import) left out"}
    return dataclasses.replace(data, q=data.q[:, keep].copy(), qd=data.qd[:, keep].copy(),
                               qdd=data.qdd[:, keep].copy(), p=data.p[:, keep].copy(),
                               meta=meta)


def stage_import(spec, plan, recorded: dict, smooth: str, folder: Path, *,
                 differences: int = 2) -> dict:
    """Import the recording with one preprocessing (``softpinn import``'s library; smoother
    ``smooth``, central differences of order ``differences`` where it has no derivative) and keep
    the bending coordinates (:func:`bending_only`)."""

    output = recorded["sensor"]["output"]
    res = import_recordings([recorded["csv"]], spec, orientation_kind=output, smooth=smooth,
                            test_trajectories=plan.test_trajectories, differences=differences)
    data = bending_only(res.data, spec)
    path = write_dataset(folder / "data.npz", data, force=True)
    truth = np.load(recorded["truth"])
    if len(truth["t"]) != len(data.t) or not np.allclose(truth["t"], data.t, atol=1e-9):
        raise AssertionError("import changed the sample times")  # it resamples only with rate
    dq = data.q - truth["q"][:, :2]
    dqd = data.qd - truth["qd"][:, :2]
    splits = data.meta["splits"]
    return {"path": str(path), "smooth": parse_smoother(smooth, differences).label,
            "samples": len(data.t),
            "train": splits["train"], "test": splits["test"], "notes": res.notes,
            "q_error_rms": float(np.sqrt(np.mean(dq**2))),
            "qd_error_rms": float(np.sqrt(np.mean(dqd**2))),
            "qd_rms_true": float(np.sqrt(np.mean(truth["qd"][:, :2] ** 2)))}


def _model_config(spec, plan, kind: str):

    m = plan.models[kind]
    return ModelConfig(kind=kind, n=2, m=spec.m, mass=tuple(m["mass"]),
                       potential=tuple(m["potential"]), damping=tuple(m["damping"]),
                       input=tuple(m["input"]), hidden=tuple(m["hidden"]),
                       dtype="float32" if plan.float32 else "float64")


def stage_train(spec, plan, kind: str, rate: float, imported: dict,
                folder: Path, progress) -> dict:

    m = plan.models[kind]
    data = load_dataset(imported["path"])
    epochs = int(m["epochs"])
    tc = TrainConfig(
        model=_model_config(spec, plan, kind), epochs=epochs, batch_size=plan.batch_size,
        lr=float(m["lr"]), seed=0, seeds=plan.seeds,
        test_trajectories=tuple(imported["test"]), samples=plan.samples,
        validation=0,  # the paper task as published: its test loss picks (docs/rundir.md)
        substeps=int(plan.substeps[rate_name(rate)]), input_hold=plan.input_hold,
        # the plan's actuator, known (none: the commands reach the arm at once, as before)
        actuator=plan.actuator_dynamics(spec.m).text(),
        prior=getattr(plan, "prior", "none"),
        eval_every=max(1, epochs // 25), checkpoint_every=max(1, epochs // 5),
    )
    run_dir = folder / "run"
    t0 = time.perf_counter()
    res = train(data, tc, run_dir, progress=progress, force=True, warn=lambda s: None)
    return {"run": str(run_dir), "metrics": res.metrics, "config": tc.to_dict(),
            "samples": int(res.metrics.get("train_pairs", 0)), "epochs": epochs,
            "seconds": time.perf_counter() - t0}


def _finite(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _rollout_errors(rollouts: list[dict], truth: dict[int, tuple[np.ndarray, np.ndarray]]):
    """Per rollout: the mean over samples after t0 of the squared bending error against the
    processed measurement and against the true arm, and the per-coordinate rms against the
    truth (inf where the prediction left the finite numbers)."""
    vs_data, vs_truth, rms = [], [], []
    for r in rollouts:
        tt, qt = truth[int(r["id"])]
        idx = np.searchsorted(tt, r["t"] - 1e-9)
        if not np.allclose(tt[idx], r["t"], atol=1e-9):
            raise AssertionError("rollout times are not sample times")
        qp = np.asarray(r["q_pred"])[1:, :2]
        with np.errstate(over="ignore", invalid="ignore"):
            ed = np.sum((qp - np.asarray(r["q_true"])[1:, :2]) ** 2, axis=1)
            et = (qp - qt[idx][1:, :2]) ** 2
            vals = (float(np.mean(ed)), float(np.mean(np.sum(et, axis=1))),
                    np.sqrt(np.mean(et, axis=0)))
        ok = all(np.all(np.isfinite(v)) for v in vals)
        vs_data.append(vals[0] if ok else math.inf)
        vs_truth.append(vals[1] if ok else math.inf)
        rms.append(vals[2] if ok else np.full(2, np.inf))
    return np.asarray(vs_data), np.asarray(vs_truth), np.asarray(rms)


def _stat(values) -> dict[str, Any]:
    v = np.asarray(values, float)
    finite = v[np.isfinite(v)]
    return {"mean": _finite(float(np.mean(v))) if v.size and finite.size == v.size else None,
            "std": _finite(float(np.std(v))) if v.size and finite.size == v.size else None,
            "diverged": int(v.size - finite.size), "count": int(v.size),
            "finite_mean": float(np.mean(finite)) if finite.size else None}


def stage_predict(plan, kind: str, rate: float, imported: dict, recorded: dict,
                  trained: dict, folder: Path) -> dict:
    data = load_dataset(imported["path"])
    test = [int(i) for i in imported["test"]]
    truth_file = np.load(recorded["truth"])
    truth = {}
    for i in test:
        rows = truth_file["traj"] == i
        truth[i] = (truth_file["t"][rows], truth_file["q"][rows])
    span = min(float(truth[i][0][-1] - truth[i][0][0]) for i in test)
    horizon = min(plan.horizon, span)
    kw = dict(substeps=int(plan.substeps[rate_name(rate)]), input_hold=plan.input_hold)
    members = []
    arrays: dict[str, np.ndarray] = {}
    recorded_data = data
    for j, run in enumerate(load_ensemble(trained["run"])):
        # the network's u is its actuator's output (the run's, as it trained)
        data = run.inputs(recorded_data)
        short = evaluate(run.model, data, test, horizon=horizon, **kw)
        reset = evaluate(run.model, data, test, horizon=span, reset_every=plan.reset_every, **kw)
        cfg = run.model_config
        pnp = make_pairs(data, imported["train"], state=cfg.state_kind,
                         samples=min(20000, len(data.t)), seed=0)
        pairs = Pairs(*(jnp.asarray(a, jnp.dtype(cfg.dtype)) for a in pnp[:5]), None)
        train_err = np.asarray(one_step_errors(run.model, pairs, weight=1.0, **kw))
        d5, t5, _ = _rollout_errors(short.rollouts, truth)
        dr, tr, rr = _rollout_errors(reset.rollouts, truth)
        members.append({"seed": run.seed, "train": train_err,
                        "test": (short.one_step_error["mean"], short.one_step_error["std"]),
                        "d5": d5, "t5": t5, "dr": dr, "tr": tr, "rr": rr})
        if j == 0:
            for name, res in (("short", short), ("reset", reset)):
                for r in res.rollouts:
                    tid = int(r["id"])
                    tt, qt = truth[tid]
                    idx = np.searchsorted(tt, r["t"] - 1e-9)
                    arrays[f"{name}_{tid}_t"] = r["t"]
                    arrays[f"{name}_{tid}_data"] = r["q_true"]
                    arrays[f"{name}_{tid}_pred"] = r["q_pred"]
                    arrays[f"{name}_{tid}_truth"] = qt[idx]
                    arrays[f"{name}_{tid}_resets"] = np.asarray(r["resets"], float)
    np.savez(folder / "rollouts.npz", **arrays)
    first = members[0]
    with np.errstate(over="ignore", invalid="ignore"):
        train_mean = float(np.mean([np.mean(m["train"]) for m in members]))
        train_std = float(np.mean([np.std(m["train"]) for m in members]))
    rr_all = np.concatenate([m["rr"] for m in members])
    return {
        "train_error": {"mean": _finite(train_mean), "std": _finite(train_std)},
        "test_error": {"mean": _finite(float(np.mean([m["test"][0] for m in members]))),
                       "std": _finite(float(np.mean([m["test"][1] for m in members])))},
        "prediction_error": {**_stat(np.concatenate([m["d5"] for m in members])),
                             "horizon_s": horizon},
        "prediction_error_truth": {**_stat(np.concatenate([m["t5"] for m in members])),
                                   "horizon_s": horizon},
        "reset_error": {**_stat(np.concatenate([m["dr"] for m in members])),
                        "horizon_s": span, "reset_every_s": plan.reset_every},
        "reset_error_truth": {**_stat(np.concatenate([m["tr"] for m in members])),
                              "horizon_s": span, "reset_every_s": plan.reset_every},
        "reset_rms_truth": (np.mean(rr_all, axis=0).tolist()
                            if np.all(np.isfinite(rr_all)) else None),
        "rollout_errors_truth": [_finite(x) for x in first["t5"]],
        "trajectories": test, "seeds": [m["seed"] for m in members],
        "rollouts": str(folder / "rollouts.npz"),
    }


def baselines_settings(plan, imp_settings: dict) -> dict:
    """The baselines stage's settings: the imported data's, the horizons, the input hold and
    the baselines fitted."""
    return {"import": imp_settings, "horizon": plan.horizon, "reset_every": plan.reset_every,
            "hold": plan.input_hold, "baselines": [list(b) for b in BASELINES]}


def stage_baselines(plan, imported: dict) -> dict:
    """No motion and the linear models (:mod:`bridge.analysis.baselines`) on the
    imported bending coordinates (the networks' data: the observed coordinates only), fitted on
    the training trajectories and scored on the test ones against the processed measurement,
    as :func:`stage_predict` scores the networks: over the horizon without reset (``short``)
    and over the whole test trajectories with the state reset every ``reset_every`` seconds
    (``reset``), under the plan's actuator as the networks are; fitted once for both (the
    lagged ARX and the rollout fit take seconds)."""
    data = load_dataset(imported["path"])
    data = with_actuator(data, plan.actuator_dynamics(data.m))  # the networks' inputs
    train_ids, test = list(imported["train"]), [int(i) for i in imported["test"]]
    span = min(float(tr["t"][-1] - tr["t"][0]) for tr in trajectories(data, test))
    horizon = min(plan.horizon, span)
    models = fit_baselines(data, train_ids, input_hold=plan.input_hold)  # fitted once
    short = score_models(models, data, train_ids, test, [horizon], input_hold=plan.input_hold)
    reset = score_models(models, data, train_ids, test, [span], reset_every=plan.reset_every,
                         input_hold=plan.input_hold)
    return {"short": short.to_json(), "reset": reset.to_json(), "horizon_s": horizon,
            "span_s": span, "reset_every_s": plan.reset_every, "input_hold": plan.input_hold}


def stage_bending(spec, plan, imported: dict, trained: dict) -> dict:
    """The Lagrangian network's matrices (it learned the bending, dx and dy) against the true
    model's bending block at dL = 0, at q drawn from the training data."""


    data = load_dataset(imported["path"])
    rows = np.flatnonzero(np.isin(data.traj, np.asarray(imported["train"])))
    pick = np.random.default_rng(0).choice(rows, size=min(plan.analysis_points, rows.size),
                                           replace=False)
    q = data.q[np.sort(pick)]
    q3 = np.concatenate([q, np.zeros((len(q), spec.n - 2))], axis=1)
    true = true_matrices(TrueModel(spec), q3)
    run = load_ensemble(trained["run"])[0]
    learned = learned_matrices(run.model, q)
    b = slice(0, 2)
    tb = MatrixStack(M=true.mass()[:, b, b], D=true.D[:, b, b], G=true.G[:, b],
                     A=true.A[:, b, :], name="true")
    lb = MatrixStack(M=learned.mass(), D=learned.D, G=learned.G, A=learned.A, name="learned")
    out: dict[str, Any] = {"points": len(q), "q_range": [q.min(0).tolist(), q.max(0).tolist()]}
    for name in ("alpha", "joint", "constant"):
        try:
            r = fit_transform(name, tb, lb, q)
        except Exception as exc:  # noqa: BLE001 - a fit that cannot run is reported, not fatal
            out[name] = {"status": "failed", "message": str(exc)}
            continue
        d = r.to_dict()
        out[name] = {"status": d["status"], "message": d["message"],
                     "residual": d["residual"], "residual_total": d["residual_total"],
                     "alpha": d["alpha"], "distance_all": d["distance_all"],
                     "alpha_per_matrix": d["params"].get("alpha_per_matrix")}
    return out
