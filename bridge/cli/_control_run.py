"""``softpinn control``: flags mapped onto :func:`softpinn.bridge.control.compare`
(:class:`~softpinn.bridge.control.ControlConfig`, :class:`~softpinn.bridge.control.MPCConfig`);
the headline is one table per reference (tracking error, solve time per step, failures). Its
parser: :mod:`bridge.cli.control`."""

from __future__ import annotations

import json
import sys

import numpy as np
from tqdm.auto import tqdm

from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.control import (
    ControlConfig,
    MPCConfig,
    arm_defaults,
    compare,
    default_input_bounds,
)
from softpinn.bridge.export import check_timeout
from softpinn.errors import UserError
from softpinn.symbolic import load_spec


def _bounds(values, m: int, flag: str):
    if values is None:
        return None
    a = np.asarray(values, float)
    if a.size not in (1, m):
        raise UserError(f"{flag}: expected {m} values (one per input) or one, got {a.size}")
    if np.any(np.isnan(a)):
        raise UserError(f"{flag}: values must be numbers, got {a.tolist()}")
    return tuple(float(v) for v in np.broadcast_to(a, (m,)))


def _check_order(u_min, u_max, *, given) -> None:
    """One line where a lower bound exceeds its upper one (before any work or file)."""
    if u_min is None or u_max is None:
        return
    bad = [j for j, (lo, hi) in enumerate(zip(u_min, u_max, strict=True)) if lo > hi]
    if bad:
        j = bad[0]
        lo = "--u-min" if given[0] else "the default lower bound"
        hi = "--u-max" if given[1] else "the default upper bound"
        raise UserError(f"--u-min/--u-max: input {j + 1}: {lo} {u_min[j]:g} exceeds {hi} "
                        f"{u_max[j]:g}")


def run(args) -> int:
    if args.runs:  # the runs are rebuilt from float64 weights (as `softpinn export`)
        enable_x64()

    spec = load_spec(args.model)
    if not (np.isfinite(args.rate) and args.rate > 0):
        raise UserError(f"--rate: expected a rate in Hz > 0, got {args.rate}")
    u_min = _bounds(args.u_min, spec.m, "--u-min")
    u_max = _bounds(args.u_max, spec.m, "--u-max")
    data_bounds = default_input_bounds(spec) if spec.m else None
    if data_bounds is not None:
        u_min = tuple(float(v) for v in data_bounds[0]) if u_min is None else u_min
        u_max = tuple(float(v) for v in data_bounds[1]) if u_max is None else u_max
    _check_order(u_min, u_max, given=(args.u_min is not None, args.u_max is not None))
    horizon, sensitivities, note = arm_defaults(spec.n, args.horizon, args.sensitivities)
    if note and not args.quiet:
        print(note, file=sys.stderr)
    mpc = MPCConfig(
        horizon=horizon, dt=1.0 / args.rate, substeps=args.substeps,
        stiffness=args.stiffness,
        weight_y=args.weight_y, weight_u=args.weight_u, weight_du=args.weight_du,
        u_min=u_min, u_max=u_max, solver=args.solver, qpsol=args.qpsol,
        max_iter=args.max_iter, codegen=not args.no_codegen,
        compile_timeout=check_timeout(args.compile_timeout), offset_free=args.offset_free,
        offset_free_rate=args.offset_free_rate,
        sensitivities=sensitivities,
    )
    config = ControlConfig(
        mpc=mpc, references=tuple(args.reference), center=args.center, radius=args.radius,
        period=args.period, hold=args.hold, duration=args.duration,
        include_true=not args.no_true, include_linear=not args.no_linear, member=args.member,
        mean=args.mean,
    )
    bar = _LazyBar(f"control {spec.name}", quiet=args.quiet)
    try:
        result = compare(
            spec, args.runs, args.out, config, force=args.force, compiler=args.compiler,
            log=bar.write, progress=bar.update, progress_total=bar.set_total,
        )
    finally:
        bar.close()
    result.pop("traces", None)
    if args.json:
        print(json.dumps(result))
    else:
        for line in headline(result):
            print(line)
        print(f"wrote {args.out}/report.md, results.json, figures/, traces/")
    failed = result.get("failed") or {}
    if failed:  # the others' results are written: exit 2 with one line naming the failures
        said = "; ".join(f"{name} ({f['stage']}): {f['error']}" for name, f in failed.items())
        raise UserError(f"control: {len(failed)} controller(s) failed: {said}; the others' "
                        f"results are in {args.out}/report.md")
    return 0


class _LazyBar:
    """A tqdm bar of control steps on stderr, opened at the first step (an input error before
    it stays one line); ``write`` prints a line above it. Nothing with ``quiet``."""

    def __init__(self, desc: str, *, quiet: bool):
        self.desc, self.quiet, self.bar, self.total = desc, quiet, None, None

    def set_total(self, total: int) -> None:
        self.total = total

    def update(self) -> None:
        if self.quiet:
            return
        if self.bar is None:
            self.bar = tqdm(desc=self.desc, total=self.total, unit="step", file=sys.stderr,
                            leave=False)
        self.bar.update()

    def write(self, line: str) -> None:
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def headline(result: dict) -> list[str]:
    """Per reference, one row per controller: error RMS and max, solve time, failures."""
    unit = result["output"]["unit"]
    cfg = result["config"]

    def num(v, fmt):
        return "n/a" if v is None else format(v, fmt)

    lines = [f"{result['model']}: MPC at {result['rate']:g} Hz, horizon {cfg['horizon']}, "
             f"{cfg['solver']}; plant: the true model (cvodes)"]
    width = max((len(n) for n in result["controllers"]), default=10) + 2
    for rname, per in result["results"].items():
        lines.append(f"{rname}: {'controller':<{width}}{'RMS [' + unit + ']':>12}"
                     f"{'max [' + unit + ']':>12}{'solve ms':>10}{'max ms':>9}  failures")
        for name, m in per.items():
            fail = f"{m['failures']}/{m['steps']}" + (" diverged" if m["diverged"] else "")
            fail += "".join(f", {k} {c}" for c, k in (m.get("failure_causes") or {}).items())
            lines.append(f"{'':<{len(rname) + 2}}{name:<{width}}"
                         f"{num(m['error_rms'], '.3g'):>12}{num(m['error_max'], '.3g'):>12}"
                         f"{num(m['solve_ms_mean'], '.2f'):>10}{num(m['solve_ms_max'], '.2f'):>9}"
                         f"  {fail}")
    for name, f in (result.get("failed") or {}).items():
        where = "building its MPC" if f["stage"] == "build" else f"on {f['stage']}"
        lines.append(f"{name}: FAILED {where}: {f['error']}")
    return lines
