"""Simulating an arm behind its actuator (issue 43, item 2): the spec's ``[actuator]`` table puts
a dead time d_j and then a first-order lag tau_j between the command u_j(t) and the input y_j
the arm feels (eq. 4's u):

    tau_j ẏ_j(t) = u_j(t - d_j) - y_j(t),    u(t) = u(0) for t < 0,    y(0) = u(0) (settled),

as :class:`softpinn.actuator.Actuator` (which applies the same to recorded commands). Here it is
exact inside the integrators: the state [q; q̇] grows by one lag state per input with tau_j > 0
(:func:`augmented_ode`), the delayed command is the signal's own formula at max(t - d_j, 0)
(:class:`Delayed`), and an input with tau_j = 0 feels y_j = u_j(t - d_j) directly.
:func:`symbolic.simulation._simulate.simulate` strips the lag states from what it returns and
records u as the commands.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from softpinn.actuator import Actuator
from softpinn.symbolic.simulation._signals import Signal


@dataclass(frozen=True)
class Delayed(Signal):
    """The command ``base`` delayed per input: u_j(max(t - delay_j, 0))."""

    base: Signal
    delay: tuple[float, ...]
    kind = "delayed"

    @property
    def m(self) -> int:
        return self.base.m

    def params(self) -> np.ndarray:
        return self.base.params()

    def structure(self) -> tuple:
        return ("delayed", self.base.structure(), self.delay)

    def symbolic(self, t, p):
        fmax = ca.fmax
        by_delay = {d: self.base.symbolic(fmax(t - d, 0.0), p) if d else self.base.symbolic(t, p)
                    for d in sorted(set(self.delay))}
        return ca.vertcat(*[by_delay[d][j] for j, d in enumerate(self.delay)])

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float).reshape(-1)
        by_delay = {d: self.base(np.maximum(t - d, 0.0)) if d else self.base(t)
                    for d in sorted(set(self.delay))}
        out = np.empty((len(t), self.m))
        for j, d in enumerate(self.delay):
            out[:, j] = by_delay[d][:, j]
        return out

    def to_dict(self) -> dict:
        return {"kind": self.kind, "base": self.base.to_dict(), "delay": list(self.delay)}


@dataclass(frozen=True)
class Actuated:
    """How one simulation carries an actuator: ``lagged`` the inputs with tau > 0 (one extra
    state each, after [q; q̇]), ``tau`` their time constants, ``delay`` every input's dead time."""

    lagged: tuple[int, ...]
    tau: tuple[float, ...]
    delay: tuple[float, ...]

    @classmethod
    def of(cls, actuator: Actuator | None, m: int) -> Actuated | None:
        """None for no actuator or the identity (the plain simulation runs)."""
        if actuator is None or actuator.is_identity or m == 0:
            return None
        tau, delay = actuator.per_input(m)
        lagged = tuple(int(j) for j in np.flatnonzero(tau > 0))
        return cls(lagged, tuple(float(tau[j]) for j in lagged), tuple(float(d) for d in delay))

    def signals(self, signals) -> list[Signal]:
        """The delayed commands u(t - d) (the signals themselves without a dead time)."""
        if not any(self.delay):
            return list(signals)
        return [Delayed(s, self.delay) for s in signals]

    def ode(self, ode: ca.Function) -> ca.Function:
        """``ode_a([q; q̇; z], w) -> [ode([q; q̇], y); (w_lag - z) / tau]``, w the delayed
        commands, y = w with the lagged inputs replaced by their states z."""
        if not self.lagged:
            return ode
        nx, m = ode.size1_in(0), ode.size1_in(1)
        xa = ca.MX.sym("x", nx + len(self.lagged))
        w = ca.MX.sym("u", m)
        z = xa[nx:]
        parts = [w[j] for j in range(m)]
        for i, j in enumerate(self.lagged):
            parts[j] = z[i]
        y = ca.vertcat(*parts)
        w_lag = ca.vertcat(*[w[j] for j in self.lagged])
        zdot = (w_lag - z) / ca.DM(self.tau)
        return ca.Function("ode_actuated", [xa, w], [ca.vertcat(ode(xa[:nx], y), zdot)],
                           ["x", "u"], ["xdot"])

    def initial(self, x0: np.ndarray, signals) -> np.ndarray:
        """[q0, q̇0, y0] with the lag states settled at the first command, y0 = u(0)."""
        if not self.lagged:
            return x0
        u0 = np.stack([s(np.zeros(1))[0] for s in signals]) if len(signals) else \
            np.zeros((0, 0))
        return np.hstack([x0, u0[:, list(self.lagged)]])

    def outputs(self, arr: np.ndarray, w: np.ndarray, nx: int) -> np.ndarray:
        """y (..., m), what the arm felt: the delayed commands ``w``, the lagged inputs' from
        the extra states of ``arr`` (..., nx + len(lagged))."""
        y = np.array(w, dtype=float, copy=True)
        if self.lagged:
            y[..., list(self.lagged)] = arr[..., nx:]
        return y
