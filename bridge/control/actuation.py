"""The actuator between the controller's commands and the arm (issue 43 item 2) in MPC.

A run with an actuator (:mod:`softpinn.actuator`) learned the arm from the actuator's output y:
per input τ ẏ = c(t - d) - y for the commands c. For control:

* :func:`actuated` augments a prediction model's state with the lag states y of the inputs with
  τ > 0 (its field becomes (ẋ, ẏ) = (f(x, y), (c - y) / τ), the inputs with τ = 0 passing c
  straight through), so the MPC plans the COMMANDS;
* the dead time is :func:`delay_steps` whole control steps: the controller (:class:`.mpc.MPC`)
  rolls its model over the commands already sent and still in transit (known) before it plans,
  and plans from there (a shift register of the last D commands);
* :func:`actuated_ode` is the same augmentation of the plant's true ODE (:func:`.loop.plant`).

A dead time that is no whole number of control steps, or differs between inputs, is refused.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator
from softpinn.errors import UserError

__all__ = ["actuated", "actuated_ode", "delay_steps", "lagged_inputs", "settled"]


def lagged_inputs(act: Actuator | None, m: int) -> np.ndarray:
    """The indices of the inputs with a lag (τ > 0): each adds one state."""
    if act is None or act.is_identity:
        return np.zeros(0, int)
    return np.flatnonzero(act.per_input(m)[0] > 0)


def delay_steps(act: Actuator | None, m: int, dt: float) -> int:
    """The dead time in control steps (one for every input)."""
    if act is None or act.is_identity:
        return 0
    delay = act.per_input(m)[1]
    if np.ptp(delay) > 0:
        raise UserError(f"control: the actuator {act.text()} has a different dead time per "
                        "input; the controller handles one dead time for all inputs")
    steps = delay[0] / dt
    if abs(steps - round(steps)) > 1e-9 * max(1.0, steps):
        raise UserError(f"control: the actuator's dead time {delay[0]:g} s is no whole number "
                        f"of control steps (dt {dt:g} s); give a --dt that divides it")
    return int(round(steps))


def settled(act: Actuator | None, m: int, u) -> np.ndarray:
    """The lag states of an actuator at rest under the commands ``u`` (y = u)."""
    return np.asarray(u, float).ravel()[lagged_inputs(act, m)]


def _augment(f, x, y, c, act: Actuator, m: int):
    """(ẋ, ẏ) with u = y on the lagged inputs, c on the others."""
    tau = act.per_input(m)[0]
    lagged = lagged_inputs(act, m)
    parts, ydot = [], []
    for j in range(m):
        if tau[j] > 0:
            i = int(np.flatnonzero(lagged == j)[0])
            parts.append(y[i])
            ydot.append((c[j] - y[i]) / tau[j])
        else:
            parts.append(c[j])
    return ca.vertcat(f(x, ca.vertcat(*parts)), *ydot)


def actuated(field: ca.Function, act: Actuator, m: int) -> ca.Function:
    """``field(x, u)`` -> ``field(z, c)`` with z = (x, y) (the same symbol type)."""
    sym = ca.MX if field.is_a("MXFunction") else ca.SX
    nx, ny = field.size1_in(0), lagged_inputs(act, m).size
    z, c = sym.sym("x", nx + ny), sym.sym("u", m)
    out = _augment(field, z[:nx], z[nx:], c, act, m)
    return ca.Function("field", [z, c], [out], ["x", "u"], ["xdot"])


def actuated_ode(ode: ca.Function, act: Actuator, m: int) -> ca.Function:
    """The true ODE (x, u) -> ẋ with the actuator's lag states appended (SX)."""
    ode = ode if ode.is_a("SXFunction") else ode.expand()
    return actuated(ode, act, m)
