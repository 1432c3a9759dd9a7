"""The settings of the model-predictive controller (:class:`MPCConfig`) and the solvers it
offers, and those of a comparison of controllers (:class:`ControlConfig`); the controller
itself is :mod:`.mpc`, the comparison :mod:`.compare`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softpinn.errors import UserError

__all__ = ["ControlConfig", "MPCConfig", "REFERENCES", "SOLVERS", "QP_SOLVERS", "SENSITIVITIES",
           "LARGE_ARM_N", "arm_defaults"]

#: From this many coordinates on (a spatial arm of three segments), ``softpinn control``'s
#: defaults are a horizon of 10 and the lifted sensitivities (:func:`arm_defaults`)
LARGE_ARM_N = 9

#: the references :func:`~softpinn.bridge.control.compare` knows
REFERENCES = ("circle", "step")

#: the MPC solvers: Gauss-Newton SQP (compiled C, dense QP) and IPOPT (exact Hessian)
SOLVERS = ("sqp", "ipopt")
#: dense QP solvers for the SQP's box-constrained steps (all ship with CasADi's wheels)
QP_SOLVERS = ("daqp", "qpoases", "osqp", "proxqp", "highs", "qrqp")
#: how the SQP gets each step's sensitivities: RK4's exact variational equations, one
#: Jacobian per step held over it (several times faster for a network's field), or that
#: about the last plan's predicted states (one rollout per solve)
SENSITIVITIES = ("exact", "frozen", "lifted")


@dataclass(frozen=True)
class MPCConfig:
    """Horizon, step, RK4 sub-steps of the prediction, weights, input bounds, solver settings.

    Weights: ``weight_y`` on the squared output error (per unit of y², e.g. m²),
    ``weight_u`` on (u - u_ref)², ``weight_du`` on the squared input change per step.
    ``max_iter``: iterations per control step, by default 1 for the SQP (the real-time
    iteration: one Gauss-Newton step from the shifted previous plan, as real-time NMPC does;
    more converge each solve, at a multiple of the time) and 50 for IPOPT; ``tol``: the SQP
    stops earlier when the largest input change of an iteration is below it (IPOPT: its
    tolerance).
    ``codegen``: compile the solver's Functions (and a learned run's export) to C; False runs
    them in CasADi's virtual machine, nothing compiled. ``compile_timeout``: the C
    compiler's limit in seconds per library.
    ``substeps`` is the least number of RK4 sub-steps per control step; with ``stiffness``
    > 0 and an operating point given to :class:`MPC`, a model whose linearisation there has
    eigenvalues λ gets more, until h max|λ| <= ``stiffness`` for the sub-step h (RK4 is stable
    up to about 2.8; learned models can be far stiffer than the arm).
    ``offset_free`` in [0, 1]: the gain of a state-disturbance estimate (offset-free MPC):
    the prediction becomes x_{k+1} = F(x_k, u_k) + d̂ over the whole horizon, and after each
    step the measured state's difference from the prediction updates it,
    d̂ ← d̂ + gain (x − F(x₋, u₋) − d̂). At rest this makes the model's equilibria the arm's: a
    learned model whose springs or weight are a little off would otherwise hold the arm off
    the reference. With the true model d̂ stays ~0. 0 (the default) switches it off. A loop
    that starts with the arm at rest (``MPC.reset(rest=True)``, which :func:`closed_loop` does
    when it sees the arm sit still under its first input) starts d̂ at x − F(x, u) there, what
    the model gets wrong about that equilibrium, instead of at zero.
    ``offset_free_rate`` in [0, 1] (with ``offset_free``): the disturbance drifts where a
    learned model's error changes along a moving reference, and a constant estimate lags
    it; an alpha-beta filter estimates its change per step too, r̂ ← r̂ + rate·e and
    d̂ ← d̂ + gain·e + r̂ for the miss e, so that d̂ is this step's disturbance, not the last
    one's (the horizon still predicts with d̂ constant: extrapolating r̂ over it made the
    true model's steps four times worse on task 5). 0 (the default): no rate; about
    gain² / (2 − gain) damps the filter critically.
    ``sensitivities`` (SQP): ``"exact"`` differentiates every RK4 stage of the prediction
    (four Jacobians of the model per sub-step); ``"frozen"`` takes one Jacobian per control
    step, at its midpoint, and the sensitivities RK4 gives that linearisation in closed
    form: the prediction and the cost stay exact, the Gauss-Newton step is approximate (an
    iteration that gives no step is redone with the exact sensitivities), and a solve with
    a network's field costs a fraction; ``"lifted"``: frozen, and each solve's first step
    linearised about the last plan's predicted states (shifted by a step, corrected to first
    order for the measurement), so a solve needs one rollout, the line search's
    (docs/control.md).
    """

    horizon: int = 20
    dt: float = 0.02
    substeps: int = 2
    stiffness: float = 1.5
    weight_y: float = 1e4
    weight_u: float = 0.0
    weight_du: float = 1e-2
    u_ref: tuple[float, ...] | None = None
    u_min: tuple[float, ...] | None = None
    u_max: tuple[float, ...] | None = None
    solver: str = "sqp"
    qpsol: str = "daqp"
    max_iter: int | None = None
    tol: float = 1e-6
    codegen: bool = True
    compile_timeout: float = 600.0
    offset_free: float = 0.0
    offset_free_rate: float = 0.0
    sensitivities: str = "exact"

    def __post_init__(self):
        if self.max_iter is None:
            object.__setattr__(self, "max_iter", 1 if self.solver == "sqp" else 50)
        for name in ("horizon", "substeps", "max_iter"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise UserError(f"{name}: expected an integer >= 1, got {v!r}")
        for name in ("dt", "tol", "compile_timeout"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v > 0):
                raise UserError(f"{name}: expected a finite number > 0, got {v!r}")
        for name in ("weight_y", "weight_u", "weight_du", "stiffness"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and np.isfinite(v) and v >= 0):
                raise UserError(f"{name}: expected a finite number >= 0, got {v!r}")
        if self.weight_y == 0:
            raise UserError("weight_y: must be > 0 (the output error is what MPC tracks)")
        if not (isinstance(self.offset_free, int | float) and not isinstance(
                self.offset_free, bool) and 0.0 <= self.offset_free <= 1.0):
            raise UserError(f"offset_free: expected a gain in [0, 1], got {self.offset_free!r}")
        if self.solver not in SOLVERS:
            raise UserError(f"solver: expected one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if not (isinstance(self.offset_free_rate, int | float) and not isinstance(
                self.offset_free_rate, bool) and 0.0 <= self.offset_free_rate <= 1.0):
            raise UserError(f"offset_free_rate: expected a gain in [0, 1], got "
                            f"{self.offset_free_rate!r}")
        if self.offset_free_rate > 0 and self.offset_free == 0:
            raise UserError("offset_free_rate: needs the disturbance estimate on (an "
                            "offset-free gain > 0)")
        if self.sensitivities not in SENSITIVITIES:
            raise UserError(f"sensitivities: expected one of {', '.join(SENSITIVITIES)}, got "
                            f"{self.sensitivities!r}")
        if self.sensitivities != "exact" and self.solver != "sqp":
            raise UserError(f"sensitivities: {self.sensitivities} is the SQP's; IPOPT uses "
                            "exact derivatives (leave it out, or use the sqp solver)")
        if self.qpsol not in QP_SOLVERS:
            raise UserError(f"qpsol: expected one of {', '.join(QP_SOLVERS)}, got "
                            f"{self.qpsol!r}")


@dataclass(frozen=True)
class ControlConfig:
    """What :func:`~softpinn.bridge.control.compare` compares, and on which references.

    ``mpc``: the controller's settings (every controller gets the same). ``references``:
    "circle" and/or "step" (in that order of first mention) around ``center`` (q; None: the
    middle of the spec's initial coordinates) with ``radius`` (in q's first two coordinates;
    None: 15 % of their range); one circle takes ``period`` s, each step is held ``hold`` s;
    ``duration`` (s) overrides both lengths. ``include_true`` / ``include_linear``: the
    controllers with the true model and with it linearised at the centre, beside the runs';
    ``member`` / ``mean``: the ensemble member exported of each run (default: its best), or
    the mean of their fields.
    """

    mpc: MPCConfig = field(default_factory=MPCConfig)
    references: tuple[str, ...] = REFERENCES
    center: tuple[float, ...] | None = None
    radius: float | None = None
    period: float = 4.0
    hold: float = 1.0
    duration: float | None = None
    include_true: bool = True
    include_linear: bool = True
    member: int | None = None
    mean: bool = False

    def __post_init__(self):
        if not isinstance(self.mpc, MPCConfig):
            raise UserError(f"mpc: expected an MPCConfig, got {type(self.mpc).__name__}")
        references = tuple(dict.fromkeys(self.references))
        for name in references:
            if name not in REFERENCES:
                raise UserError(f"reference: expected one of {', '.join(REFERENCES)}, got "
                                f"{name!r}")
        if not references:
            raise UserError("reference: give at least one reference")
        object.__setattr__(self, "references", references)
        if self.center is not None:
            object.__setattr__(self, "center", tuple(
                float(v) for v in np.asarray(self.center, float).ravel()))
        if self.radius is not None:
            radius = float(self.radius)
            if not (np.isfinite(radius) and radius >= 0):
                raise UserError(f"radius: expected a finite number >= 0, got {radius!r}")
            object.__setattr__(self, "radius", radius)
        for key in ("period", "hold"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value > 0):
                raise UserError(f"{key}: expected a number of seconds > 0, got {value!r}")
        if self.duration is not None and not (np.isfinite(self.duration) and self.duration > 0):
            raise UserError(f"duration: expected a number of seconds > 0, got "
                            f"{self.duration!r}")


def arm_defaults(n: int, horizon: int | None, sensitivities: str | None
                 ) -> tuple[int, str, str | None]:
    """(horizon, sensitivities, note) for an arm of ``n`` coordinates where the user gave
    ``horizon``/``sensitivities`` or None: :class:`MPCConfig`'s defaults (20, exact), and from
    :data:`LARGE_ARM_N` coordinates on a horizon of 10 and the lifted sensitivities, with a
    note saying so. Measured on a 3-segment arm (issue 46, docs/control.md): exact at horizon
    20 took 125 ms per solve, lifted at 10 takes 10-12 ms (median) with the same tracking and
    no failed solve; exact at 10 still 75 ms."""
    d = MPCConfig()
    large = n >= LARGE_ARM_N
    h = horizon if horizon is not None else (10 if large else d.horizon)
    s = sensitivities if sensitivities is not None else ("lifted" if large else d.sensitivities)
    chosen = [text for text, given in ((f"horizon {h}", horizon), (f"{s} sensitivities",
                                                                   sensitivities))
              if given is None]
    note = (f"note: an arm of n = {n} coordinates: {' and '.join(chosen)} (real time at this "
            "size; --horizon and --sensitivities choose otherwise)"
            if large and chosen else None)
    return h, s, note
