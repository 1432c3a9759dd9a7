"""``softpinn predict``: flags mapped onto :func:`softpinn.learn.predict`; the errors at each
horizon, the baselines beside them (:mod:`bridge.analysis.baselines`: no motion and the
linear models, fitted on the run's training trajectories and scored on the same
trajectories as the model) with the one verdict line, and what the run's numbers need said
beside them (:mod:`bridge.cli.runnotes`; its parser: :mod:`bridge.cli.predict`).

Several horizons cost one load and one rollout: the model is rolled out over the longest, and
each shorter horizon's errors are that rollout's first seconds (the rollout from the true start
under the true inputs, re-set on the same grid, is the same whatever its length). With
``--dt`` the grid of each horizon is its own, so each is rolled out on its own (the same
compiled program).

A run of ``train --model linear`` (:mod:`bridge.cli._train_run`) holds no network: its
baselines are read back and scored the same way, and the best of them named."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from softpinn.bridge.analysis.baselines import (
    BASELINES,
    BaselineComparison,
    BaselineScore,
    compare_baselines,
    fit_baselines,
    score_models,
    verdict,
)
from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli.runnotes import member_notes, note_interrupted, ran_away_text
from softpinn.errors import UserError
from softpinn.learn import (
    baseline_from_dict,
    load_dataset,
    predict,
    read_json,
    run_actuator,
    with_actuator,
)

#: ``config.json``'s model kind of a ``train --model linear`` run
LINEAR = "linear"
#: the file in a run's folder that keeps the baselines predict fitted (their fits take seconds)
BASELINE_CACHE = "baselines.json"


def fmt(x) -> str:
    return "inf" if x is None or not math.isfinite(x) else f"{x:.4e}"


def run(args) -> int:
    enable_x64()

    if Path(args.run).is_file() and Path(args.data).is_dir():
        raise UserError(f"RUN {args.run} is a file and DATA {args.data} a folder; the order is "
                        "`softpinn predict RUN DATA.npz`")

    traj = args.trajectories
    if len(traj) == 1 and traj[0] in ("auto", "test", "all"):
        traj = traj[0]
    else:
        try:
            traj = [int(t) for t in traj]
        except ValueError:
            raise UserError(
                f"--trajectories takes 'test', 'all' or integer ids, got {' '.join(traj)}"
            ) from None
    horizons = _horizons(args.horizon)
    linear = linear_run_info(args.run)
    if linear is not None:
        return _predict_linear(args, linear, traj, horizons)
    results = _evaluate(args, traj, horizons)
    outs = [res.to_json() for res in results]
    out = outs[-1]
    note_interrupted(out["run"])
    for note in member_notes(args.run, SimpleNamespace(seed=out["seed"]), args.member):
        print(f"softpinn: note: {note}", file=sys.stderr)
    comparison = line = None
    if not args.no_baselines:
        info = read_json(Path(out["run"]) / "config.json")
        data = load_dataset(args.data, n=info["model"]["n"], m=info["model"]["m"])
        data = with_actuator(data, run_actuator(info["train"].get("actuator", "auto"), data.m))
        comparison = _comparison(info, data, out["trajectories"], horizons, args.reset_every,
                                 info["train"].get("input_hold", "constant"),
                                 Path(out["run"]) / BASELINE_CACHE)
        if comparison is not None:
            line = verdict(f"{out['model']} network",
                           {r.horizon: r.rollout_error_mean for r in results}, comparison)
    if args.json:
        doc = outs[0] if len(outs) == 1 else {"horizons": horizons, "results": outs}
        if comparison is not None:
            doc = {**doc, "baselines": comparison.to_json(), "verdict": line}
        print(json.dumps(doc, allow_nan=False))
        return 0
    one = out["one_step_error"]
    print(f"one-step error: {fmt(one['mean'])} ± {fmt(one['std'])} over {one['pairs']} pairs")
    extra = ""
    if args.reset_every:
        extra += f", reset every {args.reset_every:g} s"
    if args.dt:
        extra += f", dt {args.dt:g} s"
    count = len(out["trajectories"])
    for res, o in zip(results, outs, strict=True):
        print(
            f"rollout error ({res.horizon:g} s{extra}): {fmt(o['rollout_error_mean'])} ± "
            f"{fmt(o['rollout_error_std'])} over {count} trajector{'y' if count == 1 else 'ies'}"
            f"{ran_away_text(res)}"
        )
    if comparison is not None:
        _print_baselines(comparison, horizons)
        print(f"verdict: {line}")
    if out["plot"]:
        longest = f" (the {horizons[-1]:g} s rollout)" if len(horizons) > 1 else ""
        print(f"plot: {out['plot']}{longest}")
    return 0


def _horizons(values) -> list[float]:
    """The horizons given, each a positive number of seconds, ascending, each once."""
    for v in values:
        if not (math.isfinite(v) and v > 0):
            raise UserError(f"horizon: expected a positive number of seconds, got {v!r}")
    return sorted({float(v) for v in values})


def _evaluate(args, traj, horizons):
    """predict's result at each horizon (ascending): the longest rolled out (and plotted), the
    shorter ones its first seconds; with --dt each rolled out on its own grid."""
    kw = dict(reset_every=args.reset_every, dt=args.dt, trajectories=traj, member=args.member)
    full = predict(args.run, args.data, horizon=horizons[-1], plot=args.plot, force=args.force,
                   **kw)
    if args.dt is not None:
        return [*(predict(args.run, args.data, horizon=h, **kw) for h in horizons[:-1]), full]
    return [*(first_seconds(full, h) for h in horizons[:-1]), full]


def first_seconds(res, horizon: float):
    """``res`` (a :class:`softpinn.learn.PredictResult` on the data's grid) cut to its first
    ``horizon`` seconds: the samples with t - t0 <= horizon, as a rollout over ``horizon``
    keeps them, and their errors (predict's: the mean over the samples after t0 of ‖q - q̂‖²,
    inf where not finite)."""
    rolls = []
    for ro in res.rollouts:
        t = np.asarray(ro["t"])
        keep = t - t[0] <= horizon * (1 + 1e-12) + 1e-12
        if int(keep.sum()) < 2:
            raise UserError(f"horizon: {horizon} s is shorter than the first step of trajectory "
                            f"{ro['id']}")
        q_true, q_pred = ro["q_true"][keep], ro["q_pred"][keep]
        d = q_pred[1:] - q_true[1:]
        with np.errstate(over="ignore", invalid="ignore"):
            err = float(np.mean(np.sum(d * d, axis=1)))
        resets = np.asarray(ro["resets"])
        rolls.append({**ro, "t": t[keep], "q_true": q_true, "q_pred": q_pred,
                      "error": err if math.isfinite(err) else float("inf"),
                      "resets": resets[resets <= t[keep][-1]]})
    r = np.array([ro["error"] for ro in rolls])
    with np.errstate(invalid="ignore", over="ignore"):
        mean, std = float(np.mean(r)), float(np.std(r))
    return dataclasses.replace(res, rollout_error_mean=mean, rollout_error_std=std,
                               rollout_errors=[float(x) for x in r], horizon=float(horizon),
                               rollouts=rolls, plot=None, extra=dict(res.extra))


# ------------------------------------------------------------------------------- baselines


def _comparison(info, data, test, horizons, reset_every, input_hold, cache):
    """The baselines fitted on the run's training trajectories (of its training file, also
    where DATA is another file; kept in ``cache`` for the next call) and scored on ``test`` of
    ``data``; None, with a note, where the training file is not at hand."""
    train = info["split"]["train"]
    if data.sha256 == info["dataset"]["sha256"]:
        return compare_baselines(data, train, test, horizons, reset_every=reset_every,
                                 input_hold=input_hold, cache=cache)
    source = info["dataset"].get("path")
    try:
        fit_data = load_dataset(source, n=data.n, m=data.m)
        fit_data = with_actuator(fit_data, run_actuator(info["train"].get("actuator", "auto"),
                                                        data.m))
    except (UserError, OSError, TypeError, ValueError):
        fit_data = None
    if fit_data is None or fit_data.sha256 != info["dataset"]["sha256"]:
        print(f"softpinn: note: no baselines: they are fitted on the run's training "
              f"trajectories, and its training file {source} is not at hand as it was",
              file=sys.stderr)
        return None
    models = fit_baselines(fit_data, train, input_hold=input_hold, cache=cache)
    return score_models(models, data, train, test, horizons, reset_every=reset_every,
                        input_hold=input_hold)


def _ids_text(ids) -> str:
    ids = list(ids)
    return f"trajector{'y' if len(ids) == 1 else 'ies'} {', '.join(map(str, ids))}"


def _score_text(s: BaselineScore) -> str:
    out = f"; {len(s.out_of_range)} left the training range" if s.out_of_range else ""
    return f"{s.label} {fmt(s.mean)}{out}"


def _print_baselines(comparison: BaselineComparison, horizons, *, best: bool = False) -> None:
    """One line per horizon: each baseline's rollout error (mean over the trajectories)."""
    print(f"baselines (fitted on the run's training {_ids_text(comparison.train)}):")
    for h in horizons:
        scores = comparison.at(h)
        text = ", ".join(_score_text(s) for s in scores)
        if best:
            text += f"; best: {min(scores, key=lambda s: s.mean).name}"
        print(f"  {h:g} s: {text}")


# ----------------------------------------------------------------------- a linear run


def linear_run_info(run_dir) -> dict | None:
    """The config.json of a ``train --model linear`` run, or None for any other folder (whose
    loading says what it is)."""
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        return None
    try:
        info = read_json(path)
    except (UserError, OSError, ValueError):
        return None
    model = info.get("model") if isinstance(info, dict) else None
    return info if isinstance(model, dict) and model.get("kind") == LINEAR else None


def _predict_linear(args, info, traj, horizons) -> int:
    """The baselines of a linear run scored on DATA at each horizon, and the best named."""
    for flag, given in (("--member", args.member is not None), ("--dt", args.dt is not None),
                        ("--plot", args.plot is not None)):
        if given:
            raise UserError(f"{flag} applies to a network's run; {args.run} is a linear "
                            "baseline run (train --model linear), scored at the data's step")
    run_dir = Path(args.run)
    models = []
    files = info["model"]["files"]
    for name, kind, _ in BASELINES:  # a run fitted before a kind was added lacks its file
        if kind in files:
            models.append((name, baseline_from_dict(read_json(run_dir / files[kind]))))
    data = load_dataset(args.data, n=info["model"]["n"], m=info["model"]["m"])
    data = with_actuator(data, run_actuator(info.get("actuator", {}).get("text", "none"), data.m))
    same = data.sha256 == info["dataset"]["sha256"]
    if traj == "auto":
        traj = "test" if same else "all"
    if traj == "test":
        if not same:
            raise UserError(f"dataset file {data.path} is not the one run {run_dir} was fitted "
                            "on, so it has no test split; use all trajectories")
        ids = list(info["split"]["test"])
    elif traj == "all":
        ids = data.trajectory_ids.tolist()
    else:
        ids = [int(i) for i in traj]
        unknown = sorted(set(ids) - set(data.trajectory_ids.tolist()))
        if unknown:
            raise UserError(f"trajectories {unknown} are not in {data.path}")
    comparison = score_models(models, data, info["split"]["train"], ids, horizons,
                              reset_every=args.reset_every)
    best = {h: min(comparison.at(h), key=lambda s: s.mean).name for h in horizons}
    if args.json:
        doc = {"run": str(run_dir), "model": LINEAR, "dataset": data.path,
               "split": "test" if same and ids == info["split"]["test"] else "given",
               "trajectories": ids, "horizons": horizons, "reset_every": args.reset_every,
               "baselines": comparison.to_json(), "best": [best[h] for h in horizons]}
        print(json.dumps(doc, allow_nan=False))
        return 0
    extra = f", reset every {args.reset_every:g} s" if args.reset_every else ""
    print(f"linear baseline run {run_dir}: rollout error over {_ids_text(ids)}{extra}")
    _print_baselines(comparison, horizons, best=True)
    names = set(best.values())
    if len(names) == 1:
        print(f"best: {names.pop()} at every horizon")
    return 0
