"""``softpinn analyze``: the learned matrices of a run against the true model's
(:func:`softpinn.bridge.analysis.analyze`), with the report and tables
(:func:`softpinn.bridge.figures.analysis.write_report`); its parser: :mod:`bridge.cli.analyze`."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from softpinn.bridge.analysis import analysis_q, analyze
from softpinn.bridge.analysis.forces import data_samples
from softpinn.bridge.analysis.transform_result import Status, match_word
from softpinn.bridge.analysis.transforms import TRANSFORMS
from softpinn.bridge.base import outputs
from softpinn.bridge.base.release import before_claim, release
from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli.runnotes import member_notes
from softpinn.bridge.figures.analysis import write_report
from softpinn.bridge.figures.tables import percent_text
from softpinn.errors import UserError
from softpinn.learn import load_dataset, load_run
from softpinn.symbolic import TrueModel, load_spec


def run(args) -> int:
    enable_x64()

    _check_order(args.run, args.model)
    if args.points < 1 and args.q is None:
        raise UserError(f"--points: expected a count >= 1, got {args.points}")
    spec = load_spec(args.model)
    run = load_run(args.run, member=args.member)
    cfg = run.model_config
    if (cfg.n, cfg.m) != (spec.n, spec.m):
        raise UserError(
            f"run {args.run} holds a model with n={cfg.n}, m={cfg.m}; {spec.name} has "
            f"n={spec.n}, m={spec.m}"
        )
    if cfg.kind == "blackbox":
        raise UserError(f"run {args.run} holds a black-box model: it has no matrices to analyze")
    if not args.model_mismatch_ok:
        _check_same_model(run, spec, args.run)
    transforms = args.transform or ("pointwise", "joint", "alpha", "constant", "smooth")
    for name in transforms:
        if name not in TRANSFORMS:
            raise UserError(f"--transform: unknown {name!r}; expected one of {list(TRANSFORMS)}")
    if args.q is not None:
        if len(args.q) % spec.n:
            raise UserError(
                f"--q: expected a multiple of n = {spec.n} numbers for {spec.name}, "
                f"got {len(args.q)}"
            )
        q = np.asarray(args.q, dtype=float).reshape(-1, spec.n)
        if not np.all(np.isfinite(q)):
            raise UserError(f"--q: expected finite numbers, got {args.q}")
        k = len(q)
        if "smooth" in transforms and len(q) < 8:
            transforms = tuple(t for t in transforms if t != "smooth")
    elif "q0_low" in spec.data and "q0_high" in spec.data:
        q, k = analysis_q(spec, count=args.points)
    else:  # a spec without a [data] box (its data imported, or simulated with defaults)
        table, k = analysis_q(spec, count=0) if spec.training.get("matrix_q") else (
            np.zeros((0, spec.n)), 0)
        q = np.concatenate([table, _data_q(run, args.data, args.points)])
    samples = _force_samples(run, args.data, args.samples, transforms)
    state = before_claim(args.out)
    out = outputs.claim(args.out, "analyze", force=args.force)
    try:  # issue 44: a refusal after the claim leaves nothing (a new or empty --out)
        result = analyze(TrueModel(spec), run.model, q, transforms=transforms, samples=samples)
        notes = _recorded_notes(run, spec) + member_notes(args.run, run, args.member)
        for note in notes:
            print(f"softpinn: note: {note}", file=sys.stderr)
        paths = write_report(result, out, max_table_q=max(k, 3), notes=notes)
    except UserError:
        release(out, state)
        raise
    outputs.record(out, paths.values())
    if args.json:
        print(json.dumps(result.to_dict()))
    else:
        for line in _headline(result):
            print(line)
        print(f"wrote {paths['report']}" if "report" in paths else f"wrote {args.out}")
    return 0


def _recorded_notes(run, spec) -> list[str]:
    """Where the run learned from recordings (``softpinn import``), its "true" matrices are
    the spec's nominal model, not measurements: say so."""
    path = (run.info.get("dataset") or {}).get("path")
    try:
        with np.load(Path(path), allow_pickle=False) as f:
            meta = json.loads(str(f["meta"].item()))
    except Exception:  # noqa: BLE001 - the data set is elsewhere: nothing to say
        return []
    if not isinstance(meta, dict) or meta.get("source") != "import":
        return []
    return [f"the run learned from recordings ({Path(path).name}); what this analysis calls "
            f"'true' is the nominal model {spec.name}, not a measurement"]


def _check_order(run: str, model: str) -> None:
    """``analyze RUN MODEL`` with the arguments swapped or a data set for MODEL: say so."""
    m = Path(model)
    if m.is_dir() and (m / "config.json").is_file():
        raise UserError(f"model: {model} is a run directory; the order is `softpinn analyze RUN "
                        "MODEL` (MODEL: a preset name or a spec file)")
    if m.suffix == ".npz" or (m.is_file() and m.read_bytes()[:2] == b"PK"):
        raise UserError(f"model: {model} is a data set, not a model; give the preset name or spec "
                        "file of the true model (a data set to compare forces along: --data)")
    if Path(run).is_file():
        raise UserError(f"run: {run} is a file; RUN is the folder `softpinn train --out` wrote")


def _check_same_model(run, spec, run_path: str) -> None:
    """Refuse a true model that is not the one whose data the run was trained on: its physics
    (from the data set's meta when the file is there and unchanged) or else its name."""
    recorded = run.info.get("dataset", {})
    name = recorded.get("name")
    path = recorded.get("path")
    physics = None
    if path and Path(path).is_file():
        try:
            data = load_dataset(path)
        except Exception:  # noqa: BLE001 - an unreadable data set: fall back to the name
            data = None
        if data is not None and data.sha256 == recorded.get("sha256"):
            stored = data.meta.get("spec") if isinstance(data.meta, dict) else None
            if isinstance(stored, dict):
                physics = {k: v for k, v in stored.items()
                           if k not in ("name", "source", "description", "data", "training",
                                         "sensor")}
    if physics is not None:
        mine = json.loads(json.dumps(spec.physics_dict()))
        mine.pop("name", None)
        differ = sorted(k for k in set(physics) | set(mine) if physics.get(k) != mine.get(k))
        if not differ:
            return
        what = f"its physics differ in {', '.join(differ)}"
    elif name and name != spec.name:
        what = "another model"
    else:
        return
    raise UserError(
        f"model: {run_path} was trained on data of {name or 'another model'}, not {spec.name} "
        f"({what}); give the run's model, or --model-mismatch-ok to compare on purpose"
    )


def _data_q(run, data_path, count: int):
    """``count`` configurations drawn from the data (``--data``, else the run's data set): the
    q to analyse when the spec has no [data] box to sample from."""
    path = data_path or run.info.get("dataset", {}).get("path")
    if not path or not Path(path).is_file():
        raise UserError(f"model: the spec has no [data] q0_low/q0_high to sample q from and the "
                        f"run's data set {path} is not there; give --q or --data")
    q = load_dataset(path, n=run.model_config.n, m=run.model_config.m).q
    rows = np.random.default_rng(0).choice(len(q), size=min(count, len(q)), replace=False)
    return np.asarray(q)[np.sort(rows)]


def _headline(result) -> list[str]:
    """One line per transform: what its total residual means, the fit's outcome where it is not
    ok, and the residual per matrix in percent (alpha too)."""
    lines = []
    for name, r in result.results.items():
        res = ", ".join(f"{k} {percent_text(v)}" for k, v in r.residual.items()
                        if v is not None and v == v)
        alpha = f", alpha = {r.alpha:.4g}" if name == "alpha" and r.alpha is not None else ""
        if alpha and r.alpha < 0:
            alpha += " (negative: no scaled copy of the true matrices)"
        fit = "" if r.status == Status.SUCCESS else f" (fit: {r.status})"
        lines.append(f"{name}: {match_word(r.residual_total)}{fit}{alpha}; error after the "
                     f"transform, relative to the true matrix: {res}")
    return lines


def _force_samples(run, data_path, count, transforms):
    """Samples for the force and acceleration comparisons: from ``data_path`` (the run's
    training trajectories when it is the run's own data set, else all), or by default from the
    run's data set; None when ``count`` is 0 or, by default, the run's data set is gone (said
    on stderr). A Lagrangian model's forces need the alpha transform; without it only the
    accelerations are compared (said on stderr)."""
    if count < 0:
        raise UserError(f"--samples: expected 0 or more, got {count}")
    if count == 0:
        return None
    if run.model_config.kind != "hamiltonian" and "alpha" not in transforms:
        print("softpinn: note: a Lagrangian model's forces are compared through the alpha "
              "transform (not among --transform): comparing the accelerations only",
              file=sys.stderr)
    recorded = run.info.get("dataset", {})
    if data_path is None:
        data_path = recorded.get("path")
        if not data_path or not Path(data_path).is_file():
            print("softpinn: note: no force or acceleration comparison: the run's data set "
                  f"{data_path} is not there (give --data)", file=sys.stderr)
            return None
    data = load_dataset(data_path, n=run.model_config.n, m=run.model_config.m)
    # the arm feels the actuator's output, the network's u (the run's actuator; none: as recorded)
    data = run.inputs(data)
    own = data.sha256 == recorded.get("sha256")
    ids = run.info.get("split", {}).get("train") if own else None
    return data_samples(data, ids, count=count)

