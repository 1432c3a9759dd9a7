"""Smooth building blocks for PCC kinematics near zero curvature.

The PCC transform (eq. 13) contains lambda (1 - cos theta) and lambda sin theta with
lambda = L / theta. Written as ``L * theta * cosc(theta^2)`` and ``L * sinc(theta^2)`` with

    sinc(s) = sin(sqrt(s)) / sqrt(s),         cosc(s) = (1 - cos(sqrt(s))) / s,

both functions of s = theta^2 are entire (even in theta), so the transform, its Jacobians and
all higher derivatives are finite at theta = 0. Below ``SWITCH`` the functions use their Taylor
series; the direct branch is fed a safe argument there so that neither branch produces a NaN
(``if_else`` evaluates both). ``cosc`` uses 1 - cos x = 2 sin^2(x/2), free of cancellation.
"""

from __future__ import annotations

import math

import casadi as ca

#: s = x^2 below which the Taylor series is used (|x| < 0.1). The first omitted term of the
#: series is below 1e-21 relative there, and the direct formulas lose at most ~1e-13 relative
#: in their second derivatives just above it.
SWITCH = 1e-2
_TERMS = 7


def _series(s, coeffs):
    out = coeffs[-1]
    for c in reversed(coeffs[:-1]):
        out = c + s * out
    return out


# sin(x)/x = sum (-1)^k x^(2k) / (2k+1)!;  (1 - cos x)/x^2 = sum (-1)^k x^(2k) / (2k+2)!
_SINC = [(-1) ** k / math.factorial(2 * k + 1) for k in range(_TERMS)]
_COSC = [(-1) ** k / math.factorial(2 * k + 2) for k in range(_TERMS)]


def sinc(s):
    """sin(sqrt(s)) / sqrt(s) for s >= 0, exact and smooth at s = 0 (CasADi SX/MX or float)."""
    small = s < SWITCH
    safe = ca.if_else(small, 1.0, s)
    r = ca.sqrt(safe)
    return ca.if_else(small, _series(s, _SINC), ca.sin(r) / r)


def cosc(s):
    """(1 - cos(sqrt(s))) / s for s >= 0, exact and smooth at s = 0 (CasADi SX/MX or float)."""
    small = s < SWITCH
    safe = ca.if_else(small, 1.0, s)
    h = 0.5 * ca.sqrt(safe)
    sh = ca.sin(h) / h
    return ca.if_else(small, _series(s, _COSC), 0.5 * sh * sh)


def _derivative_coeffs(coeffs, order):
    out = list(coeffs)
    for _ in range(order):
        out = [k * c for k, c in enumerate(out)][1:]
    return out


#: jet switch: the closed-form derivatives below lose ~eps / s relative accuracy; at s >= 0.1
#: that is below 1e-13 up to the second derivative, and 8 series terms are exact to 1e-19.
JET_SWITCH = 0.1
_JET_TERMS = 8


class Jet:
    """cosc and sinc of one argument s(q) as symbols with their derivatives in s up to the
    second, for cheap exact derivatives of the PCC transform.

    Write an expression with :attr:`c1` (= cosc(s)) and :attr:`c2` (= sinc(s)) as if they
    were symbols, differentiate it with :meth:`jacobian` / :meth:`jtimes` (total derivatives:
    the chain rule through s uses the symbols of the derivatives), and call :meth:`finalize`
    to substitute the actual values: a Taylor series below :data:`JET_SWITCH`, else closed
    forms sharing one sqrt, sin and cos,

        sinc' = (cos r - sinc) / (2 s),   sinc'' = -(sinc / 2 + 3 sinc') / (2 s),
        cosc' = (sinc - 2 cosc) / (2 s),  cosc'' = (sinc' - 4 cosc') / (2 s),   r = sqrt(s).

    Derivatives of third order are refused (they would need more symbols).
    """

    def __init__(self):
        self.sym = ca.SX.sym("jet", 6)  # cosc, cosc', cosc'', sinc, sinc', sinc''
        self._third = ca.SX.sym("jet3", 2)
        s = self.sym
        self._next = ca.vertcat(s[1], s[2], self._third[0], s[4], s[5], self._third[1])
        self.s = None

    @property
    def c1(self):
        return self.sym[0]

    @property
    def c2(self):
        return self.sym[3]

    def bind(self, s):
        """Record the argument s (an SX expression); returns self."""
        self.s = s
        return self

    def jacobian(self, expr, q):
        """Total Jacobian d expr / d q through s."""
        ds = ca.jacobian(self.s, q)
        return ca.jacobian(expr, q) + ca.jacobian(expr, self.sym) @ (self._next @ ds)

    def jtimes(self, expr, q, v):
        """Total directional derivative of expr along v."""
        ds = ca.jtimes(self.s, q, v)
        return ca.jtimes(expr, q, v) + ca.jtimes(expr, self.sym, self._next * ds)

    def values(self, s):
        """The six values at s (SX), series below JET_SWITCH, closed forms above."""
        small = s < JET_SWITCH
        safe = ca.if_else(small, 1.0, s)
        r = ca.sqrt(safe)
        sn, cs = ca.sin(r), ca.cos(r)
        c2 = sn / r
        c2d = (cs - c2) / (2 * safe)
        c2dd = -(0.5 * c2 + 3 * c2d) / (2 * safe)
        c1 = (1 - cs) / safe
        c1d = (c2 - 2 * c1) / (2 * safe)
        c1dd = (c2d - 4 * c1d) / (2 * safe)
        closed = [c1, c1d, c1dd, c2, c2d, c2dd]
        cosc_c = [(-1) ** k / math.factorial(2 * k + 2) for k in range(_JET_TERMS)]
        sinc_c = [(-1) ** k / math.factorial(2 * k + 1) for k in range(_JET_TERMS)]
        series = [_series(s, _derivative_coeffs(c, o)) for c in (cosc_c, sinc_c) for o in range(3)]
        return ca.vertcat(*(ca.if_else(small, a, b) for a, b in zip(series, closed, strict=True)))

    def finalize(self, exprs):
        """Substitute the values for the symbols in a list of expressions."""
        for e in exprs:
            if ca.depends_on(e, self._third):
                raise AssertionError("third derivative of cosc/sinc requested")
        return ca.substitute(list(exprs), [self.sym], [self.values(self.s)])
