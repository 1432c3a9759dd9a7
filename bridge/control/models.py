"""Prediction models for model-predictive control, all with the same face.

A :class:`PredictionModel` holds an SX vector field ``field(x, u) -> ẋ`` in its own state, a map
from the measured state (q, q̇) to that state (p = M(q) q̇ for a Hamiltonian network, eq. 7)
and an output map ``output(q) -> y`` (the arm's tip position, or q itself). Sources:

* :func:`from_export`: a network exported by ``softpinn export`` (its ``field`` and, for a
  Hamiltonian network, ``M``); :func:`from_run` exports a trained run first;
* :func:`from_true`: the exact PCC model's ODE (eqs. 13-24), the best case;
* :func:`linearised`: the true model linearised at one state and input (ẋ = f₀ + Jx Δx + Ju Δu).

A model with an actuator (issue 43 item 2; an export of a run that has one, or
:func:`actuate`) has the actuator's lag states appended to its state (:mod:`.actuation`): its
``u`` is then the commands, and ``actuator`` says the lag and the dead time.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator
from softpinn.bridge.control.actuation import actuated, lagged_inputs
from softpinn.bridge.export import export_run, load_exported, model_params
from softpinn.bridge.export.layers import mlp
from softpinn.bridge.export.verify import read_export
from softpinn.errors import UserError
from softpinn.learn import load_run
from softpinn.symbolic import planar_plate, spatial_tip

__all__ = ["PredictionModel", "actuate", "from_export", "from_run", "from_true", "linearised",
           "tip_output", "output_label", "resolve_run"]


@dataclass
class PredictionModel:
    """``field`` (x, u) -> ẋ (an SX Function; MX for a black box rebuilt from its weights),
    ``to_state`` (q, q̇) -> x, ``output`` q -> y.

    ``info``: where the model comes from (kind, run, export directory, seconds to export).
    ``actuator``: the actuator between the commands u and the arm (None: the identity); its
    lag states follow x in the field's state (``nx`` values in all)."""

    name: str
    n: int
    m: int
    field: ca.Function
    to_state: Callable[[np.ndarray, np.ndarray], np.ndarray]
    output: ca.Function
    info: dict = field(default_factory=dict)
    actuator: Actuator | None = None
    #: (x, u) -> (ẋ, ∂ẋ/∂(x, u)) when the source knows a cheaper form than differentiating
    #: ``field`` (the true model: :func:`_true_jacobian`); None: CasADi's jacobian of ``field``
    jacobian: ca.Function | None = None

    @property
    def nx(self) -> int:
        """The size of the field's state: (q, q̇) or (q, p), then the actuator's lag states."""
        return 2 * self.n + lagged_inputs(self.actuator, self.m).size

    def __post_init__(self):
        if self.field.size1_in(0) != self.nx or self.field.size1_in(1) != self.m:
            raise UserError(
                f"prediction model {self.name}: field must take x ({self.nx}) and u "
                f"({self.m}), got ({self.field.size1_in(0)}) and ({self.field.size1_in(1)})"
            )
        if self.output.size1_in(0) != self.n:
            raise UserError(f"prediction model {self.name}: the output map takes "
                            f"{self.output.size1_in(0)} coordinates, the model has {self.n}")


def _sx(fn: ca.Function) -> ca.Function:
    """An SX copy of ``fn`` (MX functions are expanded: the solvers see plain expressions)."""
    return fn if fn.is_a("SXFunction") else fn.expand()


def tip_output(spec) -> ca.Function:
    """y(q): the tip of the last segment of a PCC arm (3-D spatial, 2-D planar, in metres);
    q itself for other models."""
    q = ca.SX.sym("q", spec.n)
    last = len(spec.segments) - 1
    if spec.kind == "spatial-pcc":

        y = spatial_tip(spec, q, last)[1]
    elif spec.kind == "planar-pcc":

        y = planar_plate(spec, q, last, 1.0)
    else:
        y = q
    return ca.Function("output", [q], [y], ["q"], ["y"])


def output_label(spec) -> tuple[list[str], str]:
    """Names of the output's components and their unit (for tables and figure axes)."""
    if spec.kind == "spatial-pcc":
        return ["x", "y", "z"], "m"
    if spec.kind == "planar-pcc":
        return ["x", "y"], "m"
    unit = "m" if spec.kind == "mass-spring-damper" else "rad"
    return list(spec.coordinate_names), unit


def _identity_state(q, qd):
    return np.concatenate([np.asarray(q, float).ravel(), np.asarray(qd, float).ravel()])


def from_export(directory, output: ca.Function, name: str | None = None) -> PredictionModel:
    """The exported network in ``directory`` (see :mod:`softpinn.bridge.export`)."""

    directory = Path(directory)
    meta, verified = read_export(directory)  # issue 44: checksums before CasADi sees a file
    fns = load_exported(directory)
    n, m = int(meta["n"]), int(meta["m"])
    to_state = _identity_state
    if meta["state_kind"] == "momentum":
        if "M" not in fns:
            raise UserError(f"{directory}: a momentum-state model needs M to map q̇ to p")
        M = fns["M"]

        def to_state(q, qd, M=M):
            p = np.asarray(M(q)) @ np.asarray(qd, float).ravel()
            return np.concatenate([np.asarray(q, float).ravel(), p.ravel()])

    field_fn = _sx(fns["field"])
    rebuilt = _blackbox_mx(meta, field_fn) if meta["kind"] == "blackbox" else None
    info = {"source": "export", "kind": meta["kind"], "state_kind": meta["state_kind"],
            "export": str(directory), "run": meta.get("run", {}).get("path"),
            "seeds": meta.get("ensemble", {}).get("seeds"),
            "data_spec": meta.get("training", {}).get("data_spec"),
            "q_range": meta.get("training", {}).get("q_range"),
            "field": "MX from the run's weights" if rebuilt is not None else "SX",
            "verified": verified}
    model = PredictionModel(name or meta["kind"], n, m, rebuilt or field_fn, to_state, output,
                            info)
    act = meta.get("actuator")  # exports written before actuators have none
    if act and not act.get("identity", False):
        act = Actuator.from_dict({k: act[k] for k in ("time_constant", "delay", "source")
                                  if k in act}, m)
        model = actuate(model, act)
    return model


def actuate(model: PredictionModel, act: Actuator | None) -> PredictionModel:
    """``model`` driven through the actuator ``act`` (:mod:`.actuation`): its state gets the
    lag states, its input becomes the commands. The identity (or None) returns ``model``."""
    if act is None or act.is_identity:
        return model
    if model.actuator is not None and not model.actuator.is_identity:
        raise UserError(f"prediction model {model.name}: already has an actuator")
    info = {**model.info, "actuator": {**act.to_dict(), "text": act.text()}}
    return PredictionModel(model.name, model.n, model.m, actuated(model.field, act, model.m),
                           model.to_state, model.output, info, act)


def _blackbox_mx(meta: dict, field_sx: ca.Function) -> ca.Function | None:
    """A black box's field rebuilt in MX from its run's weights (dense matrix products): its
    Jacobian stays a few matrix products, where the SX copy (every weight a scalar
    instruction) grows to millions of instructions for a 128 x 5 network. None when the run
    is gone or changed since the export (its checksum), or the two copies disagree."""
    members = [Path(p) for p in (meta.get("run") or {}).get("members") or []]
    if not members or not all((p / "model.eqx").is_file() for p in members):
        return None
    h = hashlib.sha256()
    for d in members:
        for name in ("config.json", "model.eqx"):
            h.update(f"{name}\0".encode())
            h.update((d / name).read_bytes())
    if h.hexdigest() != meta["run"].get("sha256"):
        return None


    n, m = int(meta["n"]), int(meta["m"])
    x, u = ca.MX.sym("x", 2 * n), ca.MX.sym("u", m)
    outs = [mlp(model_params(load_run(p).model)["mlp"], ca.vertcat(x, u)) for p in members]
    total = outs[0]
    for o in outs[1:]:
        total = total + o
    fn = ca.Function("field", [x, u], [total / len(outs) if len(outs) > 1 else total],
                     ["x", "u"], ["xdot"])
    rng = np.random.default_rng(0)
    for _ in range(3):
        xs, us = rng.uniform(-1, 1, 2 * n), rng.uniform(-1, 1, m)
        a, b = np.asarray(fn(xs, us)), np.asarray(field_sx(xs, us))
        if not np.allclose(a, b, rtol=1e-9, atol=1e-9):
            return None
    return fn


def resolve_run(path) -> tuple[Path, str]:
    """``(directory, what)`` for a RUN argument: an export directory (``"export"``), a run
    written by ``softpinn train`` (``"run"``), or a stage folder of ``softpinn reproduce``
    holding ``run/`` (``"run"``). Anything else is a one-line error."""
    p = Path(path)
    if not p.is_dir():
        raise UserError(f"RUN {p}: not a softpinn run directory (no such directory)")
    meta = p / "model.json"
    if meta.is_file():
        try:
            fmt = json.loads(meta.read_text()).get("format")
        except (OSError, ValueError, AttributeError):
            fmt = None
        if fmt == "softpinn-export":
            return p, "export"
    if (p / "config.json").is_file():
        return p, "run"
    if (p / "run" / "config.json").is_file():
        return p / "run", "run"
    raise UserError(f"RUN {p}: not a softpinn run directory (no config.json) nor an export "
                    "directory (no model.json)")


def _check_sizes(path, directory: Path, output: ca.Function) -> None:
    """One line before any export where a run models another arm than the plant's."""
    try:
        info = json.loads((directory / "config.json").read_text())
        n = int(info["model"]["n"])
        data = info.get("dataset") or {}
    except (OSError, ValueError, KeyError, TypeError):
        return  # the export says what is wrong
    if n != output.size1_in(0):
        what = f" (trained on {data['name']} data)" if data.get("name") else ""
        raise UserError(f"runs: {path} models an arm of n = {n} coordinates{what}; the plant "
                        f"has {output.size1_in(0)}: give runs trained on data of the plant's "
                        "model")


def from_run(path, output: ca.Function, *, export_dir, name: str | None = None,
             member: int | None = None, mean: bool = False, force: bool = True,
             compiler=None, compile: bool = True, compile_timeout: float = 600.0,
             log=None) -> PredictionModel:
    """A trained run (or an export directory) as a prediction model; a run is exported to
    ``export_dir`` first (:func:`softpinn.bridge.export.export_run`; ``compile``: build its
    model.so, which the prediction model does not use: it runs the ``.casadi`` Functions;
    ``compile_timeout``: the compiler's limit in seconds; ``log``: told each stage)."""
    directory, what = resolve_run(path)
    if what == "run":
        _check_sizes(path, directory, output)
    seconds = 0.0
    if what == "run":

        t0 = time.perf_counter()
        export_run(directory, export_dir, member=member, mean=mean, force=force,
                   compiler=compiler, compile=compile, compile_timeout=compile_timeout, log=log)
        seconds = time.perf_counter() - t0
        directory = Path(export_dir)
    elif member is not None or mean:
        raise UserError(f"--member/--mean: {path} is an export directory (one model already); "
                        "export the run again to choose another member")
    model = from_export(directory, output, name)
    model.info["export_seconds"] = seconds
    return model


def _true_jacobian(true_model, ode: ca.Function) -> ca.Function:
    """(x, u) -> (ẋ, ∂ẋ/∂(x, u)) of the PCC model's ODE through its inverse dynamics: with
    τ(q, q̇, q̈) = M(q) q̈ + C(q, q̇) q̇ + G(q) + D q̇ (eq. 4 without the input) and
    q̈ = M⁻¹ (A(q) u − ...) the forward dynamics,

        ∂q̈/∂(q, q̇) = −M⁻¹ ∂(τ − A u)/∂(q, q̇) at q̈ fixed,    ∂q̈/∂u = M⁻¹ A,

    the implicit-function form: no derivative of the symbolic factorisation of M, which
    CasADi's jacobian of the ODE carries. For a 3-segment arm 357 k instructions instead of
    581 k (issue 46; the same Jacobian to rounding, tests/test_control_large.py). None
    (differentiate the ODE) where that is smaller (one segment) or the form does not hold."""
    n, m = true_model.n, true_model.m
    fns = {k: _sx(true_model.functions[k]) for k in ("inverse", "A", "M")}
    x, u, a = ca.SX.sym("x", 2 * n), ca.SX.sym("u", m), ca.SX.sym("a", n)
    q, qd = x[:n], x[n:]
    f = ode(x, u)
    A = fns["A"](q)
    residual = fns["inverse"](q, qd, a) - ca.mtimes(A, u)
    dres = ca.Function("dres", [x, u, a], [ca.jacobian(residual, x)])
    M = fns["M"](q)
    Jx = -ca.solve(M, dres(x, u, f[n:]))
    Ju = ca.solve(M, A)
    J = ca.vertcat(ca.horzcat(ca.SX.zeros(n, n), ca.SX.eye(n), ca.SX.zeros(n, m)),
                   ca.horzcat(Jx, Ju))
    # the form holds where the ODE's q̈ solves τ(q, q̇, q̈) = A u: checked at a few states,
    # else (a model whose ODE is more than eq. 4) CasADi's jacobian of the ODE
    res_fn = ca.Function("residual", [x, u, a], [residual])
    rng = np.random.default_rng(0)
    for _ in range(3):
        xs = np.concatenate([rng.uniform(-1e-2, 1e-2, n), rng.uniform(-0.1, 0.1, n)])
        us = rng.uniform(-1.0, 1.0, m)
        a0 = np.asarray(ode(xs, us)).ravel()[n:]
        r = np.asarray(res_fn(xs, us, a0)).ravel()
        scale = np.max(np.abs(np.asarray(fns["M"](xs[:n])) @ a0)) + 1.0
        if not np.all(np.isfinite(r)) or np.max(np.abs(r)) > 1e-8 * scale:
            return None
    implicit = ca.Function("mpc_field_jac", [x, u], [f, J])
    # the smaller of the two: the implicit form pays off from two segments on (146 k
    # against 208 k instructions); for one segment (41 k against 39 k) it does not
    plain = ca.Function("mpc_field_jac", [x, u], [f, ca.jacobian(f, ca.vertcat(x, u))])
    return implicit if implicit.n_instructions() < plain.n_instructions() else None


def from_true(true_model, output: ca.Function, name: str = "true") -> PredictionModel:
    """The exact model (``softpinn.symbolic.TrueModel``): its ``ode`` (x = (q, q̇), u), with
    its Jacobian through the inverse dynamics for a PCC arm (:func:`_true_jacobian`)."""
    ode = _sx(true_model.functions["ode"])
    jac = _true_jacobian(true_model, ode) if true_model.spec.kind in _PCC else None
    return PredictionModel(name, true_model.n, true_model.m, ode, _identity_state, output,
                           {"source": "true", "kind": "true"}, jacobian=jac)


#: the model kinds whose ODE is eq. 4's q̈ = M⁻¹ (A u − C q̇ − G − D q̇) with these Functions
_PCC = ("spatial-pcc", "planar-pcc")


def linearised(true_model, x0, u0, output: ca.Function, name: str = "linearised"):
    """The true ODE linearised at (x0, u0): ẋ ≈ f(x0, u0) + ∂f/∂x (x - x0) + ∂f/∂u (u - u0)."""
    ode = _sx(true_model.functions["ode"])
    n, m = true_model.n, true_model.m
    x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", m)
    f = ode(x, u)
    jac = ca.Function("linearise", [x, u], [f, ca.jacobian(f, x), ca.jacobian(f, u)])
    x0, u0 = np.asarray(x0, float).ravel(), np.asarray(u0, float).ravel()
    f0, Jx, Ju = (np.asarray(v) for v in jac(x0, u0))
    lin = ca.DM(f0) + ca.mtimes(ca.DM(Jx), x - x0) + ca.mtimes(ca.DM(Ju), u - u0)
    field_fn = ca.Function("field", [x, u], [lin], ["x", "u"], ["xdot"])
    return PredictionModel(name, n, m, field_fn, _identity_state, output,
                           {"source": "linearised", "kind": "linearised",
                            "x0": x0.tolist(), "u0": u0.tolist()})
