"""The comparison behind ``softpinn control``: MPC with several prediction models on one plant.

:func:`compare` steers the true model (cvodes, :func:`~.loop.plant`) along each reference with
one MPC per prediction model: the true model itself (the best case), each learned run (exported
to CasADi in-process, :func:`~.models.from_run`) and the true model linearised at the
reference's centre. It writes into ``out``:

* ``results.json``: the settings, the machine, and per reference and controller the tracking
  error (RMS, max, final, in the units of the output), input effort, solver failures (per
  cause, :mod:`.failures`), SQP iterations and solve time per step (mean, median, p95, max in
  ms), and the build time; the controllers that ``failed`` (each with its error in one line),
  what a failed solve applies (``fallback``) and whether the run was ``interrupted``;
* ``report.md``: the same as tables, with the figures;
* ``figures/``: per reference the paths (3-D for a spatial arm), the outputs and the error over
  time, the inputs and the solve times;
* ``traces/<reference>.npz``: the time series (t, r, and y, u, x, solve seconds, success per
  controller) for your own plots;
* ``models/<name>/``: each run's export (``softpinn export``'s files).

A controller that raises does not stop the others, and Ctrl-C stops between control steps;
either way what finished is written (issue 46, :mod:`.stepping`, :mod:`.interrupt`).

Runs with an actuator (issue 43 item 2) plan the commands through it (:mod:`.actuation`); the
plant is then the arm behind that actuator, and the true and linearised controllers know it too
(runs with different actuators are refused: they would need different plants).
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import platform
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn import locks
from softpinn._version import __version__
from softpinn.bridge.base import outputs
from softpinn.bridge.base.outputs import to_jsonable
from softpinn.bridge.base.release import before_claim, release
from softpinn.bridge.control.actuation import delay_steps
from softpinn.bridge.control.config import REFERENCES, ControlConfig
from softpinn.bridge.control.failures import fallback
from softpinn.bridge.control.interrupt import Interrupts
from softpinn.bridge.control.loop import plant
from softpinn.bridge.control.models import (
    PredictionModel,
    actuate,
    from_run,
    from_true,
    linearised,
    output_label,
    resolve_run,
    tip_output,
)
from softpinn.bridge.control.mpc import MPC, input_bounds
from softpinn.bridge.control.references import (
    check_lengths,
    circle_reference,
    circle_start,
    default_center,
    default_radius,
    equilibrium,
    fitted_radius,
    step_reference,
    step_targets,
)
from softpinn.bridge.control.report import write_report
from softpinn.bridge.control.stepping import _line, run_controllers  # noqa: F401 - _line was here
from softpinn.errors import UserError
from softpinn.files import atomic_write, write_json
from softpinn.symbolic import TrueModel, load_spec

__all__ = ["compare", "ControlConfig", "REFERENCES", "FORMAT"]

FORMAT = "softpinn-control"
#: the most control steps of one reference
MAX_STEPS = 1_000_000


def machine() -> str:
    """CPU model, cores, system, Python (for timings in results.json and report.md)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()}, "
            f"Python {platform.python_version()}")


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _references(tm, output, names, *, dt, horizon, center, radius, period, hold, duration):
    """Per reference: times, the reference rows r_1 ..., the start (x0, u0) and settings."""
    refs = {}
    for name in names:
        if name == "circle":
            q0, u0 = equilibrium(tm, circle_start(center, radius))
            info = {"kind": "circle", "center": center, "radius": radius, "period": period}
        elif name == "step":
            q0, u0 = equilibrium(tm, center)
            targets = [equilibrium(tm, q)[0] for q in step_targets(center, radius)]
            info = {"kind": "step", "center": center, "radius": radius, "hold": hold,
                    "targets": targets}
        else:
            raise UserError(f"reference: expected one of {', '.join(REFERENCES)}, got "
                            f"{name!r}")
        steps = _steps(_length(name, tm.n, period, hold, duration), dt)
        times = np.arange(1, steps + horizon + 1) * dt
        if name == "circle":
            R = circle_reference(output, center, radius, period, times)
        else:
            # past the end the last target holds: the preview does not anticipate a step that
            # never comes
            R = step_reference(output, targets, hold, np.minimum(times, steps * dt))
        info.update(duration=steps * dt, steps=steps, q0=q0, u0=u0)
        refs[name] = {"R": R, "steps": steps, "x0": np.concatenate([q0, np.zeros(tm.n)]),
                      "u0": u0, "info": info}
    return refs


def _length(name: str, n: int, period: float, hold: float, duration: float | None) -> float:
    """Seconds of the reference ``name``: ``duration``, else one round of the circle or each
    step target (two or four, :func:`step_targets`) held ``hold``."""
    if duration is not None:
        return duration
    return period if name == "circle" else hold * (4 if n > 1 else 2)


def _steps(length: float, dt: float) -> int:
    steps = int(round(length / dt))
    if steps < 1:
        raise UserError(f"duration: {length:g} s is shorter than one control step ({dt:g} s)")
    if steps > MAX_STEPS:  # a rate or duration no comparison finishes (nor fits in memory)
        raise UserError(f"rate: {1 / dt:g} Hz over {length:g} s is {steps} control steps; "
                        f"at most {MAX_STEPS} per reference")
    return steps


def _unique(name: str, taken) -> str:
    if name not in taken:
        return name
    i = 2
    while f"{name}-{i}" in taken:
        i += 1
    return f"{name}-{i}"


@locks.scope()  # the output's lock is given up when the call returns
def compare(model, runs: Sequence = (), out=None, config: ControlConfig | None = None, *,
            names: Sequence[str] | None = None, compiler=None, force: bool = False,
            log: Callable[[str], None] | None = None,
            progress: Callable[[], None] | None = None,
            progress_total: Callable[[int], None] | None = None) -> dict:
    """Compare MPC with each prediction model on the plant ``model`` (a preset name, spec file
    or :class:`~softpinn.symbolic.ModelSpec`); returns what ``results.json`` holds.

    ``runs``: trained runs (``softpinn train`` directories, ``softpinn reproduce`` stage
    folders holding ``run/``) or ``softpinn export`` directories, named ``names`` (default:
    their model kinds). ``config`` (default ``ControlConfig()``): the controller's settings,
    the references, the controllers beside the runs' and the ensemble member exported of each
    run (:class:`~.config.ControlConfig`). ``compiler``: the C compiler of the generated code.
    ``out``: the folder written (None: nothing is written); one that holds anything but an
    earlier comparison is refused unless ``force``. ``log``: called with one line per finished
    simulation, before each controller is built and for each that failed (the result's
    ``failed``; the call returns all the same). Ctrl-C raises ``KeyboardInterrupt`` after
    the control step in flight, once what finished is written. ``progress``: once per step;
    ``progress_total``: once, before the first step, with the number of steps of all the
    simulations (controllers x references). A refusal
    after ``out`` was claimed removes the claim where ``out`` was new or empty
    (:mod:`.release`).
    """
    claimed: list = []
    try:
        with Interrupts() as guard:  # Ctrl-C: stop between steps, keep what finished
            return _compare(model, runs, out, config, names=names, compiler=compiler,
                            force=force, log=log, progress=progress,
                            progress_total=progress_total, claimed=claimed, guard=guard)
    except UserError:
        for folder, fresh in claimed:
            release(folder, fresh)
        raise


def _compare(model, runs, out, config, *, names, compiler, force, log, progress,
             progress_total, claimed: list, guard: Interrupts) -> dict:
    t_start = time.perf_counter()
    config = ControlConfig() if config is None else config
    if not isinstance(config, ControlConfig):
        raise UserError(f"config: expected a ControlConfig, got {type(config).__name__}")
    mpc_config = config.mpc
    spec = load_spec(model)
    if spec.m == 0:
        raise UserError(f"model: {spec.name} has no inputs (actuation none): there is nothing "
                        "to control; give a spec with an actuation")
    runs = list(runs)
    if not (config.include_true or config.include_linear or runs):
        raise UserError("runs: nothing to compare (no run, and the true and linearised "
                        "controllers are off)")
    if names is not None and len(names) != len(runs):
        raise UserError(f"names: expected one name per run ({len(runs)}), got {len(names)}")
    center = (default_center(spec) if config.center is None
              else np.asarray(config.center, float).ravel())
    if center.size != spec.n or not np.all(np.isfinite(center)):
        raise UserError(f"center: expected {spec.n} finite coordinates of {spec.name} "
                        f"({', '.join(spec.coordinate_names)}), got "
                        f"{center.size if center.size != spec.n else center.tolist()}")
    radius = default_radius(spec) if config.radius is None else config.radius
    check_lengths(spec, center, radius)  # a centre that describes no arm (issue 44)
    input_bounds(mpc_config, spec.m)
    for name in config.references:  # issue 44: every argument checked before the claim
        _steps(_length(name, spec.n, config.period, config.hold, config.duration),
               mpc_config.dt)

    if out is not None:
        outputs.check(Path(out), "control", force=force)  # one line, before any work
    say = log or (lambda line: None)
    tm = TrueModel(spec)
    output = tip_output(spec)
    components, unit = output_label(spec)
    qc, uc = equilibrium(tm, center)

    # the prediction models; runs are exported to a scratch folder first, so that a bad run
    # or member fails before anything is written to ``out``
    models: list[PredictionModel] = []
    if config.include_true:
        models.append(from_true(tm, output, "true"))
    taken = {m.name for m in models} | {"linearised"}
    kinds = [_run_kind(run) for run in runs]  # every RUN checked before the first export
    scratch = tempfile.TemporaryDirectory(prefix="softpinn-control-")
    exported = {}
    try:
        for i, run in enumerate(runs):
            guard.check()
            name = _unique(names[i] if names is not None else kinds[i], taken)
            taken.add(name)
            export_dir = Path(scratch.name) / _safe(name)
            pm = from_run(run, output, export_dir=export_dir, name=name, member=config.member,
                          # the prediction model runs the .casadi Functions, never the
                          # export's model.so: no compile (392 s for a 3-segment network)
                          mean=config.mean, compiler=compiler, compile=False,
                          compile_timeout=mpc_config.compile_timeout,
                          log=lambda text, name=name: say(f"{name}: export: {text}"))
            if (pm.n, pm.m) != (spec.n, spec.m):
                raise UserError(f"runs: {run} learned a model with n = {pm.n}, m = {pm.m}; "
                                f"{spec.name} has n = {spec.n}, m = {spec.m}")
            if pm.info.get("verified") is False:
                say(f"note: {run}: an export written before checksums (model.json has no "
                    "sha256): its files are not verified")
            trained_on = pm.info.get("data_spec")
            if trained_on and trained_on != spec.name:
                say(f"note: {run} was trained on data of {trained_on}, not {spec.name}")
            if export_dir.is_dir():
                exported[name] = export_dir
            models.append(pm)
        if config.include_linear:
            models.append(linearised(tm, np.concatenate([qc, np.zeros(spec.n)]), uc, output))
        act = _plant_actuator(models, runs)
        radius = fitted_radius(tm, center, radius, *input_bounds(mpc_config, spec.m),
                               given=config.radius is not None, say=say)
        refs = _references(tm, output, config.references, dt=mpc_config.dt,
                           horizon=mpc_config.horizon + delay_steps(act, spec.m, mpc_config.dt),
                           center=center, radius=radius, period=config.period,
                           hold=config.hold, duration=config.duration)
        out_dir = None
        if out is not None:
            fresh = before_claim(out)
            out_dir = outputs.claim(out, "control", force=force)
            claimed.append((out_dir, fresh))
        if out_dir is not None:
            for pm in models:
                if pm.name in exported:
                    target = out_dir / "models" / _safe(pm.name)
                    if target.exists():
                        shutil.rmtree(target)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.move(str(exported[pm.name]), str(target))
                    pm.info["export"] = str(target)
                elif pm.info.get("source") == "export" and pm.info.get("export", "").startswith(
                        scratch.name):
                    pm.info["export"] = None
    finally:
        scratch.cleanup()

    models = [actuate(pm, act) if pm.info.get("source") in ("true", "linearised") else pm
              for pm in models]
    plant_fn = plant(tm, mpc_config.dt, actuator=act)

    if progress_total is not None:
        progress_total(len(models) * sum(int(ref["steps"]) for ref in refs.values()))
    done = run_controllers(models, refs, mpc_config, operating_point=(qc, np.zeros(spec.n), uc),
                           plant_fn=plant_fn, actuator=act, compiler=compiler, unit=unit,
                           names=spec.coordinate_names, guard=guard, say=say,
                           progress=progress, build=MPC)
    if done.failed and not done.interrupted and not any(done.results.values()):
        raise next(iter(done.errors.values()))  # nothing finished: the run fails, as before
    # issue 46: what finished is kept (and written) when a controller failed or on Ctrl-C
    results = {r: per for r, per in done.results.items() if per}
    result = {
        "format": FORMAT,
        "version": 1,
        "softpinn": __version__,
        "casadi": _casadi_version(),
        "model": spec.name,
        "machine": machine(),
        "load_average": _load(),
        "plant": {"integrator": "cvodes", "rtol": 1e-8, "atol": 1e-10,
                  "feedback": "the exact state (q, qd), no noise", "hold": "zero-order",
                  **({"actuator": {**act.to_dict(), "text": act.text(),
                                   "what": act.describe()}} if act is not None else {})},
        "output": {"what": "tip position" if spec.kind in ("spatial-pcc", "planar-pcc")
                   else "q", "components": components, "unit": unit},
        "config": dataclasses.asdict(mpc_config),
        "rate": 1.0 / mpc_config.dt,
        "references": {k: v["info"] for k, v in refs.items()},
        "controllers": done.controllers,
        "results": results,
        "failed": done.failed,
        "interrupted": done.interrupted,
        "fallback": fallback(mpc_config.solver),
        "seconds": time.perf_counter() - t_start,
    }
    result = to_jsonable(result)
    if out_dir is not None:
        traces = {r: per for r, per in done.traces.items() if per}
        written = [_write_json(out_dir / "results.json", result)]
        written += _write_traces(out_dir, refs, traces, mpc_config.dt)
        figures = []
        if not done.interrupted:  # after a Ctrl-C no figures (seconds), the rest at once
            # matplotlib only when figures are drawn (``import softpinn.bridge.control``
            # stays light)
            from softpinn.bridge.control.plots import write_figures

            figures = write_figures(out_dir / "figures", spec, refs, traces, result)
        written += [out_dir / f for f in figures]
        written.append(write_report(out_dir / "report.md", result, figures))
        outputs.record(out_dir, outputs.written_files(out_dir))
    if done.interrupted:
        if out_dir is not None:
            say(f"control: interrupted; the controllers that finished are in {out_dir}")
        raise KeyboardInterrupt
    result["traces"] = done.traces
    return result


def _plant_actuator(models, runs):
    """The actuator of the runs' models (None where none has one); runs with different ones are
    refused (one plant)."""
    acts = {}
    for pm in models:
        a = pm.actuator
        if a is not None and not a.is_identity:
            acts.setdefault(a.text(), a)
    if len(acts) > 1:
        raise UserError(f"runs: {', '.join(str(r) for r in runs)} have different actuators "
                        f"({'; '.join(acts)}); control steers one plant: give runs trained "
                        "with the same actuator")
    return next(iter(acts.values()), None)


def _run_kind(run) -> str:
    """The model kind of a run or export directory (its name in the comparison): "hamiltonian",
    with what sets it apart where the run says so: "hamiltonian from q̇, A known" for one
    trained on velocities (``--momenta velocity``) with a fixed input matrix."""
    directory, what = resolve_run(run)
    try:
        info = json.loads((directory / ("model.json" if what == "export" else
                                        "config.json")).read_text())
        kind = info["kind"] if what == "export" else info["model"]["kind"]
        train = info["training"].get("train", {}) if what == "export" else info.get("train", {})
        model = info["training"]["model"] if what == "export" else info["model"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise UserError(f"runs: {run}: its config cannot be read") from None
    name = str(kind)
    if kind == "hamiltonian" and isinstance(train, dict) and train.get("momenta") == "velocity":
        name += " from q̇"
    if isinstance(model, dict) and model.get("input_form") == "known":
        name += ", A known"
    return name


def _load() -> list[float] | None:
    """The 1, 5 and 15 minute load averages when the comparison ends: solve times on a busy
    machine (load above its cores) are longer than on an idle one."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:  # pragma: no cover - a system without load averages
        return None


def _casadi_version() -> str:
    return ca.__version__


def _write_json(path: Path, obj) -> Path:
    return write_json(path, obj, indent=1)  # strict, non-finite as null, written whole


def _write_traces(out: Path, refs, traces, dt: float) -> list[Path]:
    folder = out / "traces"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for rname, per in traces.items():
        steps = refs[rname]["steps"]
        arrays = {"r": np.concatenate([refs[rname]["R"][:1], refs[rname]["R"][:steps]]),
                  "t": np.arange(steps + 1) * dt}
        for name, res in per.items():
            key = _safe(name)
            arrays[f"{key}__y"] = res["y"]
            arrays[f"{key}__x"] = res["x"]
            arrays[f"{key}__u"] = res["u"]
            if "u_arm" in res:  # behind an actuator: what reached the arm
                arrays[f"{key}__u_arm"] = res["u_arm"]
            arrays[f"{key}__seconds"] = res["seconds"]
            arrays[f"{key}__success"] = res["success"]
            arrays[f"{key}__iterations"] = res["iterations"]
            arrays[f"{key}__exact_iterations"] = res["exact_iterations"]
            arrays[f"{key}__lifted_iterations"] = res["lifted_iterations"]
        arrays["names"] = np.array(list(per))
        path = folder / f"{rname}.npz"
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write(path, buf.getvalue())
        paths.append(path)
    return paths
