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
