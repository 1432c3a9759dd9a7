"""The actuator of a trained run (:mod:`softpinn.actuator`, issue 43 item 2) as CasADi Functions.

A run with an actuator learned the arm from the actuator's OUTPUT y (the network's ``u``); the
user's commands c reach it per input as τ ẏ = c(t - d) - y. ``softpinn export`` writes beside
the network's Functions:

* ``actuator(y, c) -> (ydot, u)``: the lag's field ẏ = (c - y) / τ per input and the input the
  network receives (y where τ > 0; c itself where τ = 0, whose ẏ is given as 0);
* ``actuator_step(y, c0, c1, dt) -> y1``: one step of the lag, exact for commands linear from c0
  to c1 over the step (``softpinn.actuator.lag``'s first-order hold; τ = 0: y1 = c1).

The dead time d is no ODE: the commands must be fed delayed by ``delay`` seconds (a shift
register of delay / dt samples), which the metadata and the export's log say.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator

__all__ = ["actuator_functions", "actuator_metadata"]


def actuator_functions(act: Actuator, m: int) -> dict:
    """``{"actuator": ..., "actuator_step": ...}`` (SX), empty for the identity."""
    if act.is_identity:
        return {}
    tau, _ = act.per_input(m)
    y, c = ca.SX.sym("y", m), ca.SX.sym("c", m)
    c0, c1, dt = ca.SX.sym("c0", m), ca.SX.sym("c1", m), ca.SX.sym("dt")
    ydot, u, y1 = [], [], []
    for j in range(m):
        if tau[j] == 0:
            ydot.append(ca.SX(0))
            u.append(c[j])
            y1.append(c1[j])
            continue
        ydot.append((c[j] - y[j]) / tau[j])
        u.append(y[j])
        a = ca.exp(-dt / tau[j])
        b1 = 1 - tau[j] / dt * (1 - a)  # the weight of the step's end value (first-order hold)
        b0 = 1 - a - b1
        y1.append(a * y[j] + b0 * c0[j] + b1 * c1[j])
    return {
        "actuator": ca.Function("actuator", [y, c], [ca.vertcat(*ydot), ca.vertcat(*u)],
                                ["y", "c"], ["ydot", "u"]),
        "actuator_step": ca.Function("actuator_step", [y, c0, c1, dt], [ca.vertcat(*y1)],
                                     ["y", "c0", "c1", "dt"], ["y1"]),
    }


def actuator_metadata(act: Actuator, m: int) -> dict:
    """model.json's ``actuator``: the numbers, the text form and what a user must do."""
    tau, delay = act.per_input(m)
    if act.is_identity:
        note = "none: the model's u is the input the arm receives (feed it directly)"
    else:
        note = (f"the model's u is the actuator's output y (tau y' = c(t - delay) - y per "
                f"input; {act.describe()}): integrate y with the Function actuator_step "
                "(or the field actuator) from the commands c")
        if np.any(delay > 0):
            note += (", and feed the commands delayed by delay seconds (a shift register of "
                     "delay / dt samples per input): the dead time is not part of any Function")
    return {**act.to_dict(), "text": act.text(), "identity": act.is_identity,
            "time_constant_per_input": tau.tolist(), "delay_per_input": delay.tolist(),
            "note": note}
