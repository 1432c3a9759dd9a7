"""Simulate the forward dynamics M q̈ + C q̇ + G + D q̇ = A u (eq. 4) of a model.

Two integrators, both driven by the model's ``"ode"`` function ``x = [q; q̇] -> ẋ`` (compiled
C where a compiler exists, see :mod:`symbolic.codegen._codegen`) and an input u(t) that is a known
function of time (:mod:`symbolic.simulation._signals`), evaluated exactly inside the integrator:

* ``cvodes`` (SUNDIALS, variable step, BDF with Newton iterations; CasADi's
  ``integrator(name, "cvodes", dae, t0, grid, opts)``) with the outputs on a fixed-rate grid.
  The Jacobian of the compiled ode comes from finite differences (``enable_fd``): an exact
  Jacobian generated as C is too large to compile for two segments (docs/pitfalls.md);
* ``rk4``: fixed-step classical Runge-Kutta with step ``dt`` (the paper's Task 5 fixed-step
  data, dt = 0.0002 s), outputs decimated to the output rate. The steps are a CasADi
  ``mapaccum`` of ``mapaccum`` (no Python loop per step).

Many trajectories run in parallel: the integrator is ``map``-ped over a chunk of trajectories
with CasADi's ``"thread"`` parallelization; chunks advance a progress callback.

When the functions are compiled (:func:`symbolic.codegen._codegen.compiled`), the work that is
plain evaluation runs in the batched C kernels of :mod:`symbolic.codegen._kernel` (the same SX
instructions, vectorised over states): ``rk4`` integrates all trajectories of a signal structure
at once in C (trajectories split over ``threads`` threads), and q̈, p and M at every output
sample (both integrators) come from one kernel. Results equal CasADi's to rounding (1e-15
relative); without a compiler, or with uncompiled functions, everything stays in CasADi.

A trajectory that reaches a singularity of the model (the ``phi-theta`` parameterization at
theta = 0, Fig. 12 of the paper) is never returned with NaN: a non-finite state, a mass
matrix with condition number above ``max_condition`` or a failure of cvodes raises
:class:`SingularityError` naming the trajectory, the time and the state.

With an ``actuator`` (a spec's ``[actuator]`` table) the arm feels the commands through a dead
time and a first-order lag per input, integrated exactly with one extra state per lagged input
(:mod:`symbolic.simulation._actuated`); what comes back is the arm's alone (x, q̈, p under what
the actuator delivered) with u the commands.

The output grid is t_k = k / rate, k = 0 .. round(duration * rate) - 1 (so 10 s at 50 Hz are
500 samples, as counted in Table III). How to integrate, what comes back and the errors are
:mod:`symbolic.simulation._sim_config`'s.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator
from softpinn.progress import Progress, ProgressFn
from softpinn.symbolic.simulation._actuated import Actuated
from softpinn.symbolic.simulation._samples import (
    batched,
    condition_numbers,
    kernel_post,
    kernel_postprocess,
    kernel_rk4,
    post_function,
    postprocess,
)
from softpinn.symbolic.simulation._signals import Signal
from softpinn.symbolic.simulation._sim_config import (
    SimResult,
    SimulationConfig,
    SimulationError,
    SingularityError,
)

# --------------------------------------------------------------------------------------------


def _signal_params(signals: Sequence[Signal]) -> np.ndarray:
    return (
        np.stack([s.params() for s in signals], axis=1)
        if signals[0].params().size
        else np.zeros((0, len(signals)))
    )


def _dae(ode: ca.Function, signal: Signal, nx: int):
    """x, tau, p = [t_start; signal params], xdot = ode(x, u(t_start + tau))."""
    x = ca.MX.sym("x", nx)
    tau = ca.MX.sym("t")
    npar = len(signal.params())
    p = ca.MX.sym("p", 1 + npar)
    u = signal.symbolic(p[0] + tau, p[1:])
    return {"x": x, "t": tau, "p": p, "ode": ode(x, u)}


def cvodes_integrator(
    ode: ca.Function,
    signal: Signal,
    nx: int,
    grid: np.ndarray,
    config: SimulationConfig,
    name: str = "sim",
) -> ca.Function:
    """A CasADi cvodes integrator with outputs at ``grid`` (starting at 0)."""
    opts = {
        "abstol": config.atol,
        "reltol": config.rtol,
        "max_num_steps": config.max_num_steps,
        "error_on_fail": True,
        "disable_internal_warnings": True,
        "show_eval_warnings": False,
    }
    return ca.integrator(name, "cvodes", _dae(ode, signal, nx), 0.0, list(grid), opts)


def rk4_integrator(
    ode: ca.Function, signal: Signal, nx: int, config: SimulationConfig
) -> ca.Function:
    """F(x0, p) -> x on the output grid (nx, T), fixed-step RK4 by nested ``mapaccum``."""
    dt = config.step
    x = ca.MX.sym("x", nx)
    t = ca.MX.sym("t")
    npar = len(signal.params())
    p = ca.MX.sym("p", npar)

    def f(xx, tt):
        return ode(xx, signal.symbolic(tt, p))

    k1 = f(x, t)
    k2 = f(x + dt / 2 * k1, t + dt / 2)
    k3 = f(x + dt / 2 * k2, t + dt / 2)
    k4 = f(x + dt * k3, t + dt)
    step = ca.Function(
        "rk4_step", [x, t, p], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], ["x", "t", "p"], ["xf"]
    )
    sub = config.substeps
    inner = step.mapaccum("rk4_substeps", sub)
    t0 = ca.MX.sym("t0")
    offsets = ca.DM(np.arange(sub) * dt).T
    xs = inner(x, t0 + offsets, p)
    sample = ca.Function("rk4_sample", [x, t0, p], [xs[:, -1]], ["x", "t0", "p"], ["xf"])
    outer = sample.mapaccum("rk4_samples", config.samples - 1)
    tgrid = ca.DM(config.times()[:-1]).T
    xo = outer(x, tgrid, p)
    return ca.Function("rk4", [x, p], [ca.horzcat(x, xo)], ["x0", "p"], ["xf"])


def simulate(
    fns: Mapping[str, ca.Function],
    x0: np.ndarray,
    signals: Sequence[Signal],
    config: SimulationConfig,
    *,
    progress: ProgressFn | None = None,
    actuator: Actuator | None = None,
) -> SimResult:
    """Integrate K trajectories from the initial states ``x0`` (K, 2n) under ``signals`` (K).

    ``fns`` holds the model's functions (keys ``"ode"``, ``"forward"``, ``"momentum"``,
    ``"M"``; see :func:`symbolic.model._functions.functions`), compiled or not. ``progress`` is
    told the trajectories finished after every chunk (a :class:`softpinn.progress.Progress`).
    ``actuator``: the commands ``signals`` reach the arm through it (the module's doc).
    """
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    ode = fns["ode"]
    nx = ode.size1_in(0)
    n = nx // 2
    m = ode.size1_in(1) if ode.n_in() > 1 else 0
    if x0.shape[1] != nx:
        raise SimulationError(
            f"initial state: expected {nx} values per trajectory (q and qd), got {x0.shape[1]}"
        )
    if not np.all(np.isfinite(x0)):
        raise SimulationError("initial state: values must be finite")
    if len(signals) != len(x0):
        raise SimulationError(
            f"signals: expected one per trajectory ({len(x0)}), got {len(signals)}"
        )
    for s in signals:
        if s.m != m:
            raise SimulationError(f"signal: expected {m} inputs, got {s.m}")
    k_all = len(x0)
    t = config.times()
    nt = len(t)
    xs = np.empty((k_all, nt, nx))
    commands, act = signals, Actuated.of(actuator, m)
    if act is not None:  # integrate [q; q̇; lag states] under the delayed commands
        x0, signals, ode = act.initial(x0, commands), act.signals(commands), act.ode(ode)
    u = np.empty((k_all, nt, m))
    qdd = np.empty((k_all, nt, n))
    mom = np.empty((k_all, nt, n))
    check = config.max_condition is not None and "M" in fns
    max_cond = 0.0 if check else None
    integrate_s = post_s = 0.0
    finished = 0
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(signals):
        groups.setdefault(s.structure(), []).append(i)
    post_fn = post_function(fns, n, m)
    post_kernel = None
    kernel_s = 0.0
    for idx in groups.values():
        proto = signals[idx[0]]
        rk = None
        if config.integrator == "cvodes":
            f = cvodes_integrator(ode, proto, ode.size1_in(0), t, config)
        else:
            start = time.perf_counter()
            rk = kernel_rk4(ode, proto, post_fn)
            kernel_s += time.perf_counter() - start
            f = (rk4_integrator(ode, proto, ode.size1_in(0), config) if rk is None
                 else None)
        if rk is not None:
            post_kernel = rk.kernels["post"]
        elif post_fn is not None and post_kernel is None:
            start = time.perf_counter()
            post_kernel = kernel_post(post_fn)
            kernel_s += time.perf_counter() - start
            if post_kernel is None:
                post_fn = None
        chunk = config.threads if rk is None else len(idx)  # the kernel: all at once
        for c0 in range(0, len(idx), chunk):
            ids = idx[c0 : c0 + chunk]
            start = time.perf_counter()
            p = _signal_params([signals[i] for i in ids])
            if rk is not None:
                arr = rk(x0[ids], p.T, nt, config.substeps, config.step, config.rate,
                         threads=config.threads)
                out = None
            else:
                fm = (f.map(len(ids), "thread", min(config.threads, len(ids)))
                      if len(ids) > 1 else f)
                if config.integrator == "cvodes":
                    p = np.vstack([np.zeros((1, len(ids))), p])
                try:
                    with _quiet_stderr():
                        out = fm(x0=x0[ids].T, p=p)["xf"]
                except RuntimeError as exc:
                    for i in ids:
                        _locate_failure(ode, signals[i], ode.size1_in(0), x0[i], t, config, i,
                                        n=n)
                    raise SingularityError(
                        f"trajectories {ids}: the integrator failed: "
                        f"{' '.join(str(exc).split())}"
                    ) from None
            if out is not None:
                arr = np.asarray(out).reshape(-1, len(ids), nt).transpose(1, 2, 0)
            xs[ids] = arr[:, :, :nx]
            for j, i in enumerate(ids):
                _check_finite(arr[j], t, i, n, integrator=config.integrator, dt=config.step)
            integrate_s += time.perf_counter() - start
            # accelerations, momenta and conditioning of this chunk (bounded memory)
            start = time.perf_counter()
            uu = np.stack([signals[i](t) for i in ids])
            u[ids] = uu if act is None else np.stack([commands[i](t) for i in ids])
            if act is not None:  # what the arm felt
                uu = act.outputs(arr, uu, nx)
                arr = arr[:, :, :nx]
            flat_u = uu.reshape(len(ids) * nt, m)
            if post_kernel is not None:
                a, pm, mm = kernel_postprocess(post_kernel, arr.reshape(-1, nx), flat_u, n,
                                               config.threads)
            else:
                a, pm, mm = postprocess(fns, arr.reshape(-1, nx), flat_u, n, config.threads)
            qdd[ids] = a.reshape(len(ids), nt, n)
            mom[ids] = pm.reshape(len(ids), nt, n)
            for j, i in enumerate(ids):
                _check_finite(np.hstack([arr[j], qdd[i]]), t, i, n, what="acceleration")
            if check:
                stride = config.condition_stride if mm is None else 1
                qs = arr[:, ::stride, :n]
                if mm is None:
                    mm = batched(fns["M"], qs.reshape(-1, n), threads=config.threads)
                cond = condition_numbers(mm.reshape(len(ids), qs.shape[1], n, n))
                max_cond = max(max_cond, float(np.max(cond)))
                bad = np.argwhere(~(cond <= config.max_condition))
                if len(bad):
                    j, ks = bad[0]
                    k = ks * stride
                    raise SingularityError(
                        f"trajectory {ids[j]}: the mass matrix is ill-conditioned (cond = "
                        f"{cond[j, ks]:.3g} > {config.max_condition:g}) at t = {t[k]:.6g} s, "
                        f"state {_fmt(arr[j, k], n)}; the model is singular there (phi-theta "
                        'at theta = 0?): use parameterization = "delta"'
                    )
            post_s += time.perf_counter() - start
            finished += len(ids)
            if progress is not None:
                progress(Progress(done=finished, total=k_all, unit="trajectory"))
    info = {
        "integrate_seconds": integrate_s,
        "postprocess_seconds": post_s,
        "max_mass_condition": max_cond,
        "kernels": post_kernel is not None,
        "kernel_build_seconds": kernel_s,
    }
    return SimResult(t=t, x=xs, u=u, qdd=qdd, p=mom, config=config, info=info)


def _fmt(x: np.ndarray, n: int) -> str:
    q = ", ".join(f"{v:.6g}" for v in x[:n])
    qd = ", ".join(f"{v:.6g}" for v in x[n:2 * n])
    return f"q = [{q}], qd = [{qd}]"


def _check_finite(
    arr: np.ndarray,
    t: np.ndarray,
    k: int,
    n: int,
    what: str = "state",
    integrator: str = "cvodes",
    dt: float = 0.0,
):
    bad = ~np.all(np.isfinite(arr), axis=1)
    if bad.any():
        j = int(np.argmax(bad))
        last = (
            f"last finite state at t = {t[j - 1]:.6g} s: {_fmt(arr[j - 1, : 2 * n], n)}"
            if j
            else f"at t = 0: {_fmt(arr[0, : 2 * n], n)}"
        )
        hint = (
            f"either the fixed step dt = {dt:g} s is too large for a stiff stretch of this "
            "trajectory (use a smaller --dt or --integrator cvodes) or the model is singular "
            'there (phi-theta at theta = 0?: use parameterization = "delta")'
            if integrator == "rk4"
            else "the model is singular there (phi-theta at theta = 0?): use parameterization = "
            '"delta"'
        )
        raise SingularityError(
            f"trajectory {k}: the {what} is not finite at t = {t[j]:.6g} s ({last}); {hint}"
        )


@contextlib.contextmanager
def _quiet_stderr():
    """Capture what C code (SUNDIALS) prints on file descriptor 2 during the block; yields a
    list that receives the captured lines (the CLI's errors stay one line)."""
    lines: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode(errors="replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())


def _locate_failure(ode, signal, nx, x0, t, config, k, n=None):
    """Integrate one output interval at a time to name where cvodes failed.

    Raises :class:`SingularityError` for a trajectory that fails; returns for one that does not.
    """
    n = nx // 2 if n is None else n  # n: the arm's coordinates (nx may hold lag states too)
    dt = t[1] - t[0]
    f = cvodes_integrator(ode, signal, nx, np.array([0.0, dt]), config, name="locate")
    x = np.asarray(x0, dtype=float)
    params = signal.params()
    for j in range(len(t) - 1):
        try:
            with _quiet_stderr() as said:
                xn = np.asarray(f(x0=x, p=np.concatenate([[t[j]], params]))["xf"])[:, -1]
        except RuntimeError as exc:
            why = " ".join(said) or str(exc).strip().splitlines()[-1]
            raise SingularityError(
                f"trajectory {k}: cvodes failed between t = {t[j]:.6g} s and {t[j + 1]:.6g} s "
                f"({why}), starting from {_fmt(x, n)}; the model is singular or stiff there "
                '(phi-theta at theta = 0?): use parameterization = "delta" or other tolerances'
            ) from None
        if not np.all(np.isfinite(xn)):
            raise SingularityError(
                f"trajectory {k}: the state is not finite at t = {t[j + 1]:.6g} s (last finite "
                f"at t = {t[j]:.6g} s: {_fmt(x, n)}); the model is singular there (phi-theta at "
                'theta = 0?): use parameterization = "delta"'
            )
        x = xn
