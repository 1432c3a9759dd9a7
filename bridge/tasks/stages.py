"""The stages of a task run (data, train, predict, floor, modes, analyze), each writing under
``OUT/<stage>/`` with a ``done.json`` of the settings that made it, so that a second call with
the same settings skips finished stages."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis import analysis_q, analyze
from softpinn.bridge.analysis.floors import drift_baseline, integration_floor
from softpinn.bridge.analysis.forces import data_samples
from softpinn.bridge.analysis.modes import modes
from softpinn.bridge.exact.serialize import spec_known_input
from softpinn.bridge.figures.analysis import summary_numbers, write_report
from softpinn.bridge.tasks.plan import REPORT_WEIGHT, Plan, Variant, data_step, own_substeps
from softpinn.errors import UserError as LearnUserError
from softpinn.learn import (
    ModelConfig,
    Pairs,
    TrainConfig,
    evaluate,
    load_dataset,
    load_ensemble,
    make_pairs,
    mass_scale,
    one_step_errors,
    resolve_momenta,
    rollouts,
    train,
    trajectories,
)
from softpinn.symbolic import TrueModel, make_dataset, resample, select_trajectories, write_dataset

# ---------------------------------------------------------------------------------- stages


def write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=2, default=jsonable))
    tmp.replace(path)


def jsonable(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    raise TypeError(f"not JSON serialisable: {type(x)}")


#: How stage records name paths inside the output folder, so that the folder can be moved,
#: copied or reached from another working directory and its finished stages still found.
OUT_MARK = "$OUT"


class Stages:
    """Runs named stages once: a stage whose ``done.json`` holds the same settings is skipped.

    Paths inside the output folder are stored as ``$OUT/<relative path>`` in the settings and
    results of ``done.json`` and given back rooted at the current output folder."""

    def __init__(self, out: Path, log: Callable[[str], None]):
        self.out = out
        self.log = log
        self.seconds: dict[str, float] = {}  # per stage, as measured when it ran
        self.ran: set[str] = set()  # the stages this call ran (not reused)
        self.quiet: set[str] = set()  # reused without a log line (run by this call's workers)
        self._root = os.path.abspath(out)

    def portable(self, x: Any) -> Any:
        """``x`` (JSON-like) with every path string inside the output folder as ``$OUT/...``."""
        if isinstance(x, dict):
            return {k: self.portable(v) for k, v in x.items()}
        if isinstance(x, list):
            return [self.portable(v) for v in x]
        if isinstance(x, str) and os.sep in x and not x.startswith(OUT_MARK):
            a = os.path.abspath(x)
            if a == self._root or a.startswith(self._root + os.sep):
                return OUT_MARK + a[len(self._root):].replace(os.sep, "/")
        return x

    def rooted(self, x: Any) -> Any:
        """The inverse of :meth:`portable`: ``$OUT/...`` strings as paths in this output folder."""
        if isinstance(x, dict):
            return {k: self.rooted(v) for k, v in x.items()}
        if isinstance(x, list):
            return [self.rooted(v) for v in x]
        if isinstance(x, str) and (x == OUT_MARK or x.startswith(OUT_MARK + "/")):
            return str(self.out.joinpath(*x[len(OUT_MARK) + 1:].split("/")))
        return x

    def finished(self, name: str, settings: Mapping[str, Any]) -> dict | None:
        """The stored record (settings, result, seconds) of stage ``name`` if it finished
        with these settings, else None."""
        done = self.out / name / "done.json"
        if not done.is_file():
            return None
        stored = json.loads(done.read_text())
        settings = self.portable(json.loads(json.dumps(settings, default=jsonable)))
        # records written before paths were stored as $OUT/... are read the same way
        return stored if self.portable(stored.get("settings")) == settings else None

    def run(self, name: str, settings: Mapping[str, Any], fn: Callable[[Path], Any]) -> Any:
        folder = self.out / name
        done = folder / "done.json"
        settings = self.portable(json.loads(json.dumps(settings, default=jsonable)))
        stored = self.finished(name, settings)
        if stored is not None:
            if name not in self.quiet:
                self.log(f"[{name}] done before, skipped")
            self.seconds[name] = float(stored.get("seconds", 0.0))
            return self.rooted(self.portable(stored["result"]))
        folder.mkdir(parents=True, exist_ok=True)
        self.log(f"[{name}] ...")
        t0 = time.perf_counter()
        result = fn(folder)
        seconds = time.perf_counter() - t0
        result = self.portable(json.loads(json.dumps(result, default=jsonable)))
        write_json(done, {"settings": settings, "result": result, "seconds": seconds})
        self.seconds[name] = seconds
        self.ran.add(name)
        self.log(f"[{name}] {seconds:.1f} s")
        return self.rooted(result)



# ---------------------------------------------------------------------------------- data


def stage_data(spec, plan: Plan, folder: Path) -> dict:

    out: dict[str, Any] = {"variants": {}}
    sources = {v.source for v in plan.variants}
    made = {}
    if "cvodes" in sources:
        made["cvodes"] = make_dataset(spec, data=plan.data, integrator="cvodes")
    if "rk4" in sources:
        fs = plan.fixed_step
        made["rk4"] = make_dataset(spec, data=plan.data, integrator="rk4", dt=fs["dt"],
                                   rate=fs["rate"], duration=fs["duration"],
                                   trajectories=fs["trajectories"])
    for variant in plan.variants:
        arrays = made[variant.source]
        if variant.rate is not None and variant.rate != arrays.meta["rate"]:
            arrays = resample(arrays, variant.rate)
        splits = arrays.meta["splits"]
        files = {}
        for role, train_ids in (("physics", splits["train"]),
                                ("blackbox", splits["blackbox_train"])):
            sel = select_trajectories(arrays, list(train_ids) + list(splits["test"]))
            path = folder / f"{variant.name}-{role}.npz"
            write_dataset(path, sel, force=True)
            files[role] = {"path": str(path), "train": list(map(int, train_ids)),
                           "test": list(map(int, splits["test"])),
                           "samples": int(sum(int((sel.traj == i).sum()) for i in train_ids))}
        files["rate"] = float(arrays.meta["rate"])
        files["timestep"] = 1.0 / float(arrays.meta["rate"])
        out["variants"][variant.name] = files
    return out


# -------------------------------------------------------------------------------- training


def _model_config(spec, plan: Plan, kind: str, data, train_ids):
    """The model of ``kind``; ``data`` (a learn Dataset) and ``train_ids`` set mass_init."""

    m = plan.models[kind]
    mass_init = None
    if m.get("mass_init") == "data":
        # Started at M⁻¹ ~ I, task4's Hamiltonian network (true M⁻¹ ~ 200) fell at once into
        # M⁻¹ ≈ 0, q̇ ≈ 0 (a test loss stuck at 4.6e-5) and never left it.
        mass_init = mass_scale(data, kind, train_ids)
    extra = {}
    if kind != "blackbox":
        extra["damping_form"] = str(m.get("damping_form", "network"))
        if m.get("known_input"):  # the recipe's known actuator model: this spec's own A(q)

            extra.update(input_form="known", known_input=spec_known_input(spec)[0])
    return ModelConfig(
        kind=kind, n=spec.n, m=spec.m, mass=tuple(m["mass"]), potential=tuple(m["potential"]),
        damping=tuple(m["damping"]), input=tuple(m["input"]), hidden=tuple(m["hidden"]),
        dtype="float32" if plan.float32 else "float64", mass_init=mass_init, **extra,
    )


def _same_run(run_dir: Path, tc) -> bool:
    """Whether ``run_dir`` holds a checkpoint of a run with exactly the settings ``tc`` (one
    interrupted before it finished is resumed; one of other settings is trained afresh)."""

    if not ((run_dir / "checkpoint.eqx").is_file() or any(run_dir.glob("seed-*/checkpoint.eqx"))):
        return False
    try:
        stored = json.loads((run_dir / "config.json").read_text())["train"]
        return TrainConfig.from_dict(stored) == tc
    except (OSError, ValueError, KeyError, TypeError):
        return False


def variant_model(plan: Plan, variant: Variant, kind: str,
                  files: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The plan of model ``kind`` as trained on ``variant``: its own sub-steps, if any, and,
    for a budget marked ``equal_steps``, as many optimizer steps as on ``physics_samples``
    pairs where the variant's training data (``files``) hold fewer (task5's 50 Hz data: 24,000
    samples, so 375 epochs where the others take 200). A network with a ``max_step`` of its
    own (``[training.<network>]``) takes its sub-steps from that, not from the variant's."""
    m = dict(plan.models[kind])
    if m.get("max_step") is not None:
        m["substeps"] = own_substeps(m, data_step(plan, variant))
    elif variant.substeps is not None:
        m["substeps"] = max(int(m["substeps"]), variant.substeps)
    m.pop("max_step", None)
    target = plan.physics_samples
    if m.pop("equal_steps", False) and target and files is not None and kind != "blackbox":
        have = int(files["physics"]["samples"])
        if 0 < have < target:
            m["epochs"] = math.ceil(int(m["epochs"]) * target / have)
    return m


def stage_train(spec, plan: Plan, kind: str, m: Mapping[str, Any], files: dict, folder: Path,
                 progress, model_changes: Mapping[str, Any] | None = None) -> dict:
    """Train model ``kind`` of the plan; ``model_changes``: fields of its ModelConfig set
    otherwise (e.g. ``input_form="known"`` with ``known_input``, the known-A study)."""
    import dataclasses


    role = "blackbox" if kind == "blackbox" else "physics"
    f = files[role]
    data = load_dataset(f["path"])  # read once: for mass_init and for training
    tc = TrainConfig(
        model=dataclasses.replace(_model_config(spec, plan, kind, data, f["train"]),
                                  **dict(model_changes or {})),
        epochs=int(m["epochs"]),
        batch_size=plan.batch_size,
        lr=float(m["lr"]),
        seed=0,
        seeds=plan.seeds,
        test_trajectories=tuple(f["test"]),
        samples=plan.physics_samples if role == "physics" else None,
        lbfgs_steps=int(m["lbfgs"]),
        substeps=int(m["substeps"]),
        input_hold=str(m["input_hold"]),
        loss=str(m.get("loss", "pair")),
        accel_labels=str(m.get("accel_labels", "recorded")),
        accel_space=str(m.get("accel_space", "acceleration")),
        test_with=str(m.get("test_with", "loss")),
        loss_weight=float(m.get("loss_weight", 1.0)),
        momenta=str(m.get("momenta", "auto")),
        eval_every=max(1, int(m["epochs"]) // 50),
        patience=m.get("patience"),
        overfit=m.get("overfit"),
        test_samples=m.get("test_samples"),
        checkpoint_every=max(1, int(m["epochs"]) // 10),
    )
    # as train() stores it (a Hamiltonian network's momenta "auto" decided for these data), so
    # that an interrupted run's config.json compares equal and the run is resumed
    tc = resolve_momenta(tc, data)
    run_dir = folder / "run"
    resume = _same_run(run_dir, tc)
    try:
        res = train(data, tc, run_dir, progress=progress, force=not resume, resume=resume)
    except LearnUserError:
        if not resume:
            raise
        # e.g. the data set was simulated again: start over
        res = train(data, tc, run_dir, progress=progress, force=True)
    return {"run": str(run_dir), "metrics": res.metrics, "config": tc.to_dict(),
            "samples": res.metrics.get("train_pairs", f["samples"]), "epochs": tc.epochs}


# ------------------------------------------------------------------------------- prediction


def stage_predict(plan: Plan, kind: str, files: dict, trained: dict, folder: Path) -> dict:
    """Train and test one-step errors, rollouts over the horizon and a long horizon (one
    rollout: the first part is the horizon's), and rollouts with another step size."""
    import jax.numpy as jnp


    f = files["blackbox" if kind == "blackbox" else "physics"]
    data = load_dataset(f["path"])
    test = f["test"]
    # a variant's data may be shorter than the plan's horizons (task5's fixed-step data): predict
    # over what the data holds and report that horizon, never more
    span = max(float(tr["t"][-1] - tr["t"][0]) for tr in trajectories(data, test))
    horizon, long_horizon = min(plan.horizon, span), min(plan.long_horizon, span)
    per_seed = []
    for run in load_ensemble(trained["run"]):
        tc, cfg = run.train_config, run.model_config
        kw = dict(substeps=tc.substeps, input_hold=tc.input_hold)
        long = evaluate(run.model, data, test, horizon=long_horizon,
                        loss_weight=REPORT_WEIGHT, **kw)
        main = [_truncated_error(r, horizon) for r in long.rollouts]
        other = rollouts(run.model, trajectories(data, test, state=cfg.state_kind),
                         horizon=horizon, dt=plan.other_dt, **kw)
        pnp = make_pairs(data, f["train"], state=cfg.state_kind,
                         samples=min(20000, f["samples"]), seed=0)
        dtype = jnp.dtype(cfg.dtype)
        pairs = Pairs(*(jnp.asarray(a, dtype) for a in pnp[:5]), None)
        train_err = one_step_errors(run.model, pairs, weight=REPORT_WEIGHT, **kw)
        per_seed.append({"seed": run.seed, "long": long, "main": np.asarray(main),
                         "other": np.asarray([r["error"] for r in other]),
                         "train": train_err, "other_rollouts": other})
    first = per_seed[0]
    arrays = {}
    for prefix, r in (("long", first["long"].rollouts[0]), ("other", first["other_rollouts"][0])):
        arrays.update({f"{prefix}_t": r["t"], f"{prefix}_q_true": r["q_true"],
                       f"{prefix}_q_pred": r["q_pred"]})
    r = first["long"].rollouts[0]
    keep = r["t"] - r["t"][0] <= horizon * (1 + 1e-12) + 1e-12
    arrays.update({"main_t": r["t"][keep], "main_q_true": r["q_true"][keep],
                   "main_q_pred": r["q_pred"][keep]})
    # the inputs of the drawn trajectory, and every test trajectory's error against the time
    # since its start (the report's error-against-horizon figure)
    drawn = next(tr for tr in trajectories(data, test) if tr["id"] == r["id"])
    arrays["long_u"] = drawn["u"][: len(r["t"])]
    arrays["main_u"] = arrays["long_u"][keep]
    arrays.update(_horizon_errors(first["long"].rollouts))
    np.savez(folder / "rollouts.npz", **arrays)

    def stat(key, pick=lambda x: x):
        return error_stats([np.asarray(pick(p[key]), float) for p in per_seed])

    test_err = stat("long", lambda res: np.asarray([res.one_step_error["mean"]]))
    test_err["std"] = float(np.mean([p["long"].one_step_error["std"] for p in per_seed]))
    return {
        "train_error": stat("train"),
        "test_error": test_err,
        "prediction_error": {**stat("main"), "horizon_s": horizon},
        "long_prediction_error": {
            **stat("long", lambda res: np.asarray(res.rollout_errors)),
            "horizon_s": long_horizon,
        },
        "other_dt_prediction_error": {**stat("other"), "dt": plan.other_dt,
                                      "horizon_s": horizon},
        "rollout_errors": first["main"].tolist(),
        "trajectories": list(map(int, test)),
        "seeds": [p["seed"] for p in per_seed],
    }


def error_stats(vals: list[np.ndarray]) -> dict[str, Any]:
    """Mean and std of errors, one array per seed (rollouts or pairs), averaged over seeds.

    A rollout that blew up has error inf: the mean and std are then inf (not NaN), as in the
    paper's Table III. How many ran away, and the other rollouts' mean and std, are kept beside
    them (``ran_away``), so that a report can say more than ``inf ± inf``."""
    with np.errstate(invalid="ignore", over="ignore"):
        means = [float(np.mean(v)) for v in vals]
        stds = [float(np.std(v)) if np.all(np.isfinite(v)) else math.inf for v in vals]
        out: dict[str, Any] = {"mean": float(np.mean(means)), "std": float(np.mean(stds))}
        if len(vals) > 1:
            spread = float(np.std(means)) if np.all(np.isfinite(means)) else math.inf
            out["seeds"] = {"mean": float(np.mean(means)), "std": spread}
    every = np.concatenate([np.ravel(v) for v in vals])
    ran_away = ~np.isfinite(every)
    if ran_away.any():
        out["ran_away"] = {"count": int(ran_away.sum()), "of": int(every.size)}
        if not ran_away.all():
            rest = every[~ran_away]
            out["ran_away"]["others"] = {"mean": float(rest.mean()), "std": float(rest.std())}
    return out


def integration(m: Mapping[str, Any]) -> dict[str, Any]:
    return {"substeps": int(m["substeps"]), "input_hold": str(m["input_hold"])}


def stage_floor(spec, kind: str, m: Mapping[str, Any], files: dict) -> dict:
    """On the test pairs: the true model's one-step loss, stepped as the model is (the floor),
    and the loss of a model that learned no forces (floors.py)."""


    f = files["blackbox" if kind == "blackbox" else "physics"]
    state = "momentum" if kind == "hamiltonian" else "velocity"
    data = load_dataset(f["path"])
    pairs = make_pairs(data, f["test"], state=state)
    err = integration_floor(TrueModel(spec), pairs, state=state, weight=REPORT_WEIGHT,
                            **integration(m))
    qd0 = make_pairs(data, f["test"], state="velocity").x0[:, spec.n:]
    drift = drift_baseline(pairs, qd0, state=state, weight=REPORT_WEIGHT)
    with np.errstate(invalid="ignore", over="ignore"):
        return {"mean": float(np.mean(err)), "std": float(np.std(err)), "pairs": len(err),
                "state": state, **integration(m),
                "no_forces": float(np.mean(drift))}


def stage_modes(spec, kind: str, files: dict, trained: dict) -> dict:
    """Eigenvalues of the true and the learned (first seed) dynamics linearised at rest at the
    training data's mean q with its mean input (modes.py)."""


    f = files["blackbox" if kind == "blackbox" else "physics"]
    data = load_dataset(f["path"])
    keep = np.isin(data.traj, np.asarray(f["train"]))
    run = load_ensemble(trained["run"])[0]
    return modes(TrueModel(spec), run.model, data.q[keep].mean(axis=0),
                 data.u[keep].mean(axis=0) if spec.m else None)


def _horizon_errors(rolls: list[dict]) -> dict[str, np.ndarray]:
    """``horizon_t`` (T,), the time since each rollout's start on the shortest one's grid, and
    ``horizon_error`` (K, T): max over q of |q - q_hat| per test trajectory (inf from where it
    diverged)."""
    size = min(len(r["t"]) for r in rolls)
    with np.errstate(over="ignore", invalid="ignore"):
        err = np.stack([np.max(np.abs(r["q_pred"][:size] - r["q_true"][:size]), axis=1)
                        for r in rolls])
    # a rollout that ran away (1000 times the truth's range from it) counts as diverged
    for j, r in enumerate(rolls):
        q = r["q_true"][:size]
        scale = max(float(np.ptp(q)), float(np.max(np.abs(q))), 1e-9)
        gone = np.flatnonzero(~(err[j] <= 1e3 * scale))
        if gone.size:
            err[j, gone[0]:] = np.inf
    return {"horizon_t": rolls[0]["t"][:size] - rolls[0]["t"][0], "horizon_error": err}


def _truncated_error(rollout: dict, horizon: float) -> float:
    """The rollout error (mean over samples after t0 of ||q - q_hat||^2) over the first
    ``horizon`` seconds of a longer rollout."""
    t = rollout["t"]
    keep = t - t[0] <= horizon * (1 + 1e-12) + 1e-12
    d = rollout["q_pred"][keep][1:] - rollout["q_true"][keep][1:]
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.mean(np.sum(d * d, axis=1)))
    return err if math.isfinite(err) else float("inf")


# --------------------------------------------------------------------------------- analysis


def stage_analyze(spec, plan: Plan, trained: dict, files: dict, folder: Path) -> dict:
    """Every seed's learned matrices against the true ones at the same q: the first seed's
    analysis in ``folder`` (the report's headline), each further seed's in ``folder/seed-S``."""


    true = TrueModel(spec)
    q, k = analysis_q(spec, count=plan.analysis_points, seed=0)
    runs = load_ensemble(trained["run"])
    # the force terms along the training trajectories the models learned from (every member
    # trained on the same data and split, so one draw of samples serves them all)
    info = runs[0].info
    # the data file as this output folder holds it (the run's config.json has the path it
    # had when it trained, which moves with the folder)
    samples = data_samples(load_dataset(files["physics"]["path"]), info["split"]["train"],
                           count=plan.analysis_points * 10)
    seeds = []
    for i, run in enumerate(runs):
        where = folder if i == 0 else folder / f"seed-{run.seed}"
        result = analyze(true, run.model, q, samples=samples)
        write_report(result, where, max_table_q=max(k, 3))
        seeds.append({"seed": run.seed, "summary": summary_numbers(result),
                      "analysis": str(where / "analysis.json")})
    return {"summary": seeds[0]["summary"], "paper_q": k, "points": len(q),
            "report": str(folder / "report.md"), "seeds": seeds}
