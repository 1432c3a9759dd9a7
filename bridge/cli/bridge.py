"""``softpinn analyze`` and ``softpinn reproduce``: flags mapped onto :mod:`bridge.analysis` and
:mod:`bridge.tasks`."""

from __future__ import annotations

import json
import sys
import time

from softpinn.bridge.analysis import analysis_q, analyze
from softpinn.bridge.analysis.forces import data_samples
from softpinn.bridge.analysis.transform_result import Status, match_word
from softpinn.bridge.analysis.transforms import TRANSFORMS
from softpinn.bridge.base import outputs
from softpinn.bridge.cli.learn import _enable_x64
from softpinn.bridge.cli.runnotes import member_notes
from softpinn.bridge.figures.analysis import write_report
from softpinn.bridge.figures.tables import percent_text
from softpinn.bridge.tasks import ReproduceConfig, reproduce
from softpinn.errors import UserError
from softpinn.learn import load_dataset, load_run
from softpinn.learn.xlaflags import use_fast_compile
from softpinn.symbolic import TrueModel, load_spec


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "analyze",
        help="learned against true M, D, G, A of a trained run, with transforms P(q)",
        description=(
            "Evaluate the true (CasADi) and learned (Equinox) matrices at the given q (default: "
            "the paper's table q of a preset and q sampled in its data range), fit the "
            "transforms P(q) relating them, and write report.md, CSV/LaTeX tables and plots."
        ),
    )
    p.add_argument("run", metavar="RUN", help="run directory written by `softpinn train`")
    p.add_argument("model", metavar="MODEL", help="preset name or spec file of the true model")
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configurations, n numbers each (several q: concatenate them)")
    p.add_argument("--points", type=int, default=200,
                   help="q sampled in the data range when --q is not given (default 200)")
    p.add_argument("--transform", nargs="+", default=None, metavar="NAME",
                   help="pointwise, joint, alpha, constant, smooth, direct (default: all but "
                        "direct; direct is added for Hamiltonian models)")
    p.add_argument("--data", metavar="DATA.npz", default=None,
                   help="compare the force terms G, D q̇, A u and the accelerations M⁻¹ times "
                        "each along these data, and say how much of the inertia they show per "
                        "direction of the true M (as `softpinn excitation`; default: the run's "
                        "own data set, its training trajectories)")
    p.add_argument("--samples", type=int, default=2000,
                   help="data samples for the force and acceleration comparisons (default "
                        "2000; 0: none)")
    p.add_argument("--out", required=True,
                   help="output directory (new, empty, or an earlier analyze's)")
    p.add_argument("--force", action="store_true",
                   help="write into an --out that holds files analyze did not write, or over "
                   "a file of an earlier analysis that was edited since (nothing is removed)")
    p.add_argument("--model-mismatch-ok", action="store_true",
                   help="compare with MODEL although the run was trained on another model's data")
    p.add_argument("--member", type=int, default=None, metavar="SEED",
                   help="the ensemble member to analyze (default: the one with the best test "
                   "loss)")
    p.add_argument("--json", action="store_true", help="print every number as one JSON object")
    p.set_defaults(func=cmd_analyze)

    r = subparsers.add_parser(
        "reproduce",
        help="a paper task end to end: simulate, train, predict, analyze, report",
        description=(
            "Run one of the paper's five tasks, or the same study of an arm of your own (its "
            "spec file): simulate its data, train the physics model(s) and the black-box "
            "baseline, predict, analyze the learned matrices and write report.md; or the "
            "paper's experiment (Section V, Table IV) on a simulated stand-in: an "
            "IMU records a tendon-driven arm, the recordings are imported with each "
            "preprocessing and at each sensor rate (docs/experiment.md); or the paper's open "
            "challenges (Section VI-B: fast Lagrangian training, a known actuator model and "
            "additional labels, Hamiltonian networks from velocity data; docs/challenges.md). "
            "Finished stages are skipped when run again with the same settings."
        ),
    )
    r.add_argument("task", metavar="TASK",
                   help="task1 ... task5, experiment, challenges, or a spec file of your own "
                        "arm (ARM.toml: its [data] and [training] recipe, or defaults)")
    r.add_argument("--quick", action="store_true", help="small settings (a minute or two)")
    r.add_argument("--out", required=True,
                   help="output directory (new, empty, or an earlier reproduce's: finished "
                        "stages are reused)")
    r.add_argument("--force", action="store_true",
                   help="write into an --out that holds files reproduce did not write, or over "
                   "a file of an earlier run that was edited since (nothing is removed)")
    r.add_argument("--seeds", type=int, default=1, help="train K seeds, report mean ± std")
    r.add_argument("--epochs", type=int, default=None, help="override every model's epochs")
    r.add_argument("--lbfgs-steps", type=int, default=None,
                   help="override every model's L-BFGS iterations after AdamW")
    r.add_argument("--float32", action="store_true", help="train in float32")
    r.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="train and analyse N models at a time, each in a process of its own, "
                        "and draw a task's figures of each data set as soon as its models are "
                        "done (the tasks and the experiment; same results, sooner on a machine "
                        "with cores to spare)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.set_defaults(func=cmd_reproduce)


def cmd_analyze(args) -> int:
    _enable_x64()
    import numpy as np



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
    out = outputs.claim(args.out, "analyze", force=args.force)
    result = analyze(TrueModel(spec), run.model, q, transforms=transforms, samples=samples)
    notes = _recorded_notes(run, spec) + member_notes(args.run, run, args.member)
    for note in notes:
        print(f"softpinn: note: {note}", file=sys.stderr)
    paths = write_report(result, out, max_table_q=max(k, 3), notes=notes)
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
    from pathlib import Path

    import numpy as np

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
    from pathlib import Path

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
    from pathlib import Path


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
    from pathlib import Path

    import numpy as np


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
    from pathlib import Path



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
    own = data.sha256 == recorded.get("sha256")
    ids = run.info.get("split", {}).get("train") if own else None
    return data_samples(data, ids, count=count)


def cmd_reproduce(args) -> int:

    if args.quick:  # compiling is most of a quick run: XLA's fast-compile settings

        use_fast_compile()
    config = ReproduceConfig(
        task=args.task, quick=args.quick, seeds=args.seeds, epochs=args.epochs,
        lbfgs_steps=args.lbfgs_steps, float32=args.float32, jobs=args.jobs,
    )
    bar = None if args.quiet else _EpochBar()

    def log(line: str) -> None:
        if bar is not None:
            bar.write(line)
    try:
        result = reproduce(config, args.out, log=log, progress=bar, force=args.force)
    finally:
        if bar is not None:
            bar.close()
    print(f"wrote {result.report} ({result.seconds:.0f} s)")
    return 0


class _EpochBar:
    """One tqdm bar per trained model, driven by the training callback; with ``--jobs``, one
    bar over the models running side by side (:class:`_ModelsBar`)."""

    def __init__(self):
        from softpinn.bridge.cli.learn import LbfgsBar

        self.bar = None
        self.key = None
        self.lbfgs = LbfgsBar()
        self.models = None

    def __call__(self, info: dict):
        from tqdm.auto import tqdm

        if info["phase"] == "models" or "model" in info:  # reproduce --jobs: models side by side
            if self.models is None:
                self.close()
                self.models = _ModelsBar()
            self.models(info)
            return
        if info["phase"] == "lbfgs" and info.get("lbfgs_done") is not None:
            self.lbfgs(info)
            return
        key = (info["label"], info["epochs"])
        if self.bar is None or key != self.key:
            self.close()
            self.bar = tqdm(total=info["epochs"], file=sys.stderr, unit="epoch",
                            dynamic_ncols=True, leave=False)
            self.key = key
            self.last = 0
        if info["phase"] == "adamw":
            self.bar.update(max(0, info["epoch"] - self.last))
            self.last = info["epoch"]
        post = {"train": f"{min(info['train_loss']):.3e}"}
        if info["test_loss"] is not None:
            post["test"] = f"{min(info['test_loss']):.3e}"
        if info["phase"] != "adamw":
            post["phase"] = info["phase"]
        self.bar.set_postfix(post, refresh=False)

    def write(self, line: str) -> None:
        """A log line: above the models' bar while models run side by side, else after closing
        the model's bar."""
        if self.models is not None and not self.models.finished:
            self.models.write(line)
            return
        self.close()
        print(line, file=sys.stderr, flush=True)

    def close(self):
        self.lbfgs.close()
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        if self.models is not None:
            self.models.close()
            self.models = None


class _ModelsBar:
    """``reproduce --jobs``: one bar over the models, and where each running one is."""

    def __init__(self):
        self.bar = None
        self.epochs: dict[str, int] = {}
        self.where: dict[str, str] = {}
        self.finished = False
        self.shown = 0.0

    def __call__(self, info: dict) -> None:
        from tqdm.auto import tqdm

        if info["phase"] == "models":
            self.epochs = dict(info["models"])
            self.bar = tqdm(total=len(self.epochs), file=sys.stderr, unit="model",
                            dynamic_ncols=True, leave=False)
            return
        if self.bar is None:
            return
        key = info["model"]
        if info["phase"] == "model-done":
            self.where.pop(key, None)
            self.bar.update(1)
            self.finished = self.bar.n >= self.bar.total
        elif info["phase"] == "lbfgs" and info.get("lbfgs_done") is not None:
            self.where[key] = f"L-BFGS {info['lbfgs_done']}/{info['lbfgs_steps']}"
        else:
            self.where[key] = f"{info['epoch']}/{info['epochs']} epochs"
        self.bar.set_postfix_str("; ".join(f"{k} {v}" for k, v in self.where.items()),
                                 refresh=False)
        now = time.monotonic()
        if now - self.shown >= 0.5 or info["phase"] == "model-done":  # at most twice a second
            self.bar.refresh()
            self.shown = now

    def write(self, line: str) -> None:
        from tqdm.auto import tqdm

        tqdm.write(line, file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
