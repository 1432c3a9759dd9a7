"""The controllers of a comparison, one after the other (:func:`~.compare.compare`'s loop).

:func:`run_controllers` builds each prediction model's MPC (a build that takes longer than
:data:`ANNOUNCE_AFTER` seconds, compiling a 3-segment arm's C takes minutes, says so while it
runs) and closes the loop on every reference. A controller that raises (its build, or one of
its loops) is recorded as failed with its error in one line (:func:`~.failures.failure`) and
the others go on (issue 46: a failed run used to throw the finished controllers away); a
Ctrl-C (:class:`~.interrupt.Interrupts`) stops after the step in flight, keeping the
controllers and references that finished.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from softpinn.bridge.control.failures import failure
from softpinn.bridge.control.interrupt import Interrupts
from softpinn.bridge.control.loop import closed_loop, metrics, outside_data
from softpinn.bridge.control.mpc import MPC

__all__ = ["Outcome", "run_controllers", "ANNOUNCE_AFTER"]

#: seconds a controller's build may take before a line says what it is doing
ANNOUNCE_AFTER = 5.0


@dataclass
class Outcome:
    """What the controllers did: ``controllers`` (build info of each that was built),
    ``results`` and ``traces`` ({reference: {controller: ...}}, the loops that finished),
    ``failed`` ({controller: :func:`~.failures.failure`}), the exceptions themselves
    (``errors``) and ``interrupted``."""

    controllers: dict = field(default_factory=dict)
    results: dict = field(default_factory=dict)
    traces: dict = field(default_factory=dict)
    failed: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    interrupted: bool = False


def run_controllers(models, refs: dict, mpc_config, *, operating_point, plant_fn, actuator,
                    compiler, unit: str, names=None, guard: Interrupts | None = None,
                    build: Callable = MPC,
                    say: Callable[[str], None] = lambda line: None,
                    progress: Callable[[], None] | None = None) -> Outcome:
    """Each model's MPC on every reference in ``refs`` against ``plant_fn``; see the module.
    ``names``: the plant's coordinate names (for a learned model that leaves its data);
    ``build``: the controller's class."""
    guard = guard or Interrupts()
    out = Outcome(results={r: {} for r in refs}, traces={r: {} for r in refs})

    def step():
        guard.check()  # a Ctrl-C stops here, between two control steps
        if progress is not None:
            progress()

    for pm in models:
        stage = "build"
        try:
            guard.check()
            # a line while a long build runs (said from a timer: a cached build says nothing)
            timer = threading.Timer(ANNOUNCE_AFTER, say, args=(_building(pm, mpc_config),))
            timer.daemon = True
            t0 = time.perf_counter()
            timer.start()
            try:
                mpc = build(pm, mpc_config, operating_point=operating_point, compiler=compiler)
            finally:
                timer.cancel()
            seconds = time.perf_counter() - t0
            if seconds > ANNOUNCE_AFTER:
                say(f"control: {pm.name}'s MPC built in {seconds:.0f} s")
            out.controllers[pm.name] = {**{k: v for k, v in pm.info.items() if k != "x0"},
                                        "build_seconds": seconds,
                                        "compiled": bool(mpc.compiled),
                                        "substeps": mpc.substeps,
                                        "compile": mpc.compile_info}
            for rname, ref in refs.items():
                stage = rname
                res = closed_loop(mpc, plant_fn, ref["x0"], ref["R"], ref["steps"],
                                  u0=ref["u0"], progress=step, actuator=actuator)
                met = metrics(res)
                if pm.info.get("q_range"):  # a learned model: did the arm leave its data?
                    met["outside_data"] = outside_data(res["x"], pm.info["q_range"],
                                                       mpc_config.dt, names)
                out.results[rname][pm.name] = met
                out.traces[rname][pm.name] = res
                say(_line(rname, pm.name, met, unit))
        except KeyboardInterrupt:
            out.interrupted = True
            break
        except Exception as exc:  # noqa: BLE001 - kept in results.json, the others go on
            if guard.pending:  # a C compiler killed by the same Ctrl-C
                out.interrupted = True
                break
            out.failed[pm.name] = info = failure(exc, stage)
            out.errors[pm.name] = exc
            if pm is not models[-1]:  # the end names it too (an early word where more follow)
                where = "building its MPC" if stage == "build" else f"on the {stage} reference"
                say(f"control: {pm.name} failed {where}: {info['error']}; going on")
    return out


def _building(pm, cfg) -> str:
    """The line said while a controller's build runs long (compiling takes minutes for large
    arms)."""
    what = ("compiling" if cfg.codegen and cfg.solver == "sqp" else "building")
    slow = ("; this can take minutes for 3+ segments, once: the library is cached"
            if what == "compiling" else "")
    return (f"control: {what} {pm.name}'s MPC (n = {pm.n}, horizon {cfg.horizon}, "
            f"{cfg.solver}{slow})")


def _line(ref: str, name: str, met: dict, unit: str) -> str:
    def num(v, fmt):
        return "n/a" if v is None else format(v, fmt)

    causes = met.get("failure_causes") or {}
    why = f" ({', '.join(f'{k} {c}' for c, k in causes.items())})" if causes else ""
    fail = f", {met['failures']} failed{why}" if met["failures"] else ""
    div = ", DIVERGED" if met["diverged"] else ""
    away = met.get("outside_data") or {}
    left = (f"; left its training data's configurations at {away['first_s']:.2f} s "
            f"({away['steps']} of {met['steps']} steps: {', '.join(away['coordinates'])})"
            if away.get("steps") else "")
    return (f"{ref} / {name}: error RMS {num(met['error_rms'], '.3g')} {unit}, max "
            f"{num(met['error_max'], '.3g')} {unit}; solve {num(met['solve_ms_mean'], '.2f')} ms "
            f"mean, {num(met['solve_ms_max'], '.2f')} ms max{fail}{div}{left}")
