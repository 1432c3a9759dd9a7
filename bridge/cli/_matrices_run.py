"""``softpinn matrices``: the true matrices of a model at one state, printed or as JSON (its
parser: :mod:`bridge.cli.matrices`)."""

from __future__ import annotations

import sys

import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic import TrueModel, dumps, load_spec


def _vector(flag: str, values, size: int, model: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.size != size:
        raise UserError(f"{flag}: model '{model}' needs {size} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"{flag}: values must be finite, got {a.tolist()}")
    return a


def run(args) -> int:
    spec = load_spec(args.model)
    q = _vector("--q", args.q, spec.n, spec.name)
    qd = _vector("--qd", args.qd, spec.n, spec.name) if args.qd is not None else None
    u = _vector("--u", args.u, spec.m, spec.name) if args.u is not None else np.zeros(spec.m)
    if args.u is not None and qd is None:
        raise UserError("--u: needs --qd (the inputs only enter qdd)")
    tm = TrueModel(spec)
    out = {
        "model": spec.name,
        "q": q,
        "M": tm.M(q),
        "M_inv": tm.M_inv(q),
        "G": tm.G(q),
        "D": tm.D(q),
        "A": tm.A(q),
        "energy": tm.energy(q, qd if qd is not None else np.zeros(spec.n)),
    }
    if qd is not None:
        out.update({"qd": qd, "u": u, "C": tm.C(q, qd), "qdd": tm.qdd(q, qd, u)})
    for key, value in out.items():
        if not isinstance(value, str) and not np.all(np.isfinite(value)):
            state = ", ".join(f"{v:.6g}" for v in q)
            raise UserError(
                f"model '{spec.name}' at q = [{state}]: {key} is not finite; the model is "
                'singular there (phi-theta at theta = 0?): use parameterization = "delta"'
            )
    plain = {k: (np.asarray(v).tolist() if not isinstance(v, str) else v) for k, v in out.items()}
    if args.json:
        print(dumps(plain, what="matrices"))
        return 0
    for note in _impossible_lengths(spec, q):
        print(f"softpinn: note: {note}", file=sys.stderr)
    labels = {"energy": ("energy T + V [J]" if qd is not None
                         else "energy V [J] (at rest: gravity and elasticity)")}
    with np.printoptions(precision=6, suppress=False, linewidth=100):
        for key, value in out.items():
            if key == "model":
                print(f"model: {value}")
                continue
            arr = np.asarray(value) + 0.0  # + 0.0: no '-0.000000e+00'
            name = labels.get(key, key)
            if arr.ndim == 2:
                print(f"{name} =\n{arr}")
            else:
                print(f"{name} = {arr}")
    return 0


def _impossible_lengths(spec, q) -> list[str]:
    """A note per segment whose length L0 + dL the configuration makes zero or negative."""
    notes = []
    for i, seg in enumerate(spec.segments or ()):
        name = f"dL{i + 1}"
        if name in spec.coordinate_names:
            length = float(seg.length) + float(q[spec.coordinate_names.index(name)])
            if length <= 0:
                notes.append(f"{name} = {q[spec.coordinate_names.index(name)]:g} makes segment "
                             f"{i + 1} {length:g} m long (rest length {seg.length:g} m): no arm "
                             "has that shape")
    return notes
