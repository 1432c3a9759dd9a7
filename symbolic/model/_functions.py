"""The CasADi Functions of a model: M, M_inv, G, D, A, C, Cqd, forward, inverse, energies,
momentum, Hamiltonian form (eq. 7) and the ODE right-hand side.

``functions(spec_or_name)`` returns a dict of ``casadi.Function`` with named inputs and outputs
(see :data:`SIGNATURES`); names are ``f"{safe_spec_name}_{key}"``. Structure, for small and fast
generated C:

* each plate density (one per PCC segment, :class:`~symbolic.derivation._energies.PlateTerms`) is
  ONE SX Function of (q, qd, zeta, w), mapped serially over the Gauss-Legendre nodes with the
  outputs summed (``Function.map`` with ``reduce_in``/``reduce_out``) inside an MX graph;
* M, G and C qd are outputs of that one mapped Function (common subexpressions shared), never
  one flat expression;
* linear solves with M use a small Cholesky factorisation written out in SX (a separate
  Function), never a symbolic inverse.
"""

from __future__ import annotations

import math
import re
from functools import lru_cache
from pathlib import Path

import casadi as ca

from softpinn.symbolic.derivation import _eom as eom
from softpinn.symbolic.derivation import _kinematics as kin
from softpinn.symbolic.derivation._energies import DEFAULT_ORDER, check_order
from softpinn.symbolic.derivation._eom import Part, SymbolicModel, derive
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import load_spec

#: key -> (input names, output names)
SIGNATURES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "M": (("q",), ("M",)),
    "M_inv": (("q",), ("M_inv",)),
    "G": (("q",), ("G",)),
    "D": (("q",), ("D",)),
    "A": (("q",), ("A",)),
    "C": (("q", "qd"), ("C",)),
    "Cqd": (("q", "qd"), ("Cqd",)),
    "forward": (("q", "qd", "u"), ("qdd",)),
    "inverse": (("q", "qd", "qdd"), ("tau",)),
    "energy": (("q", "qd"), ("E",)),
    "kinetic": (("q", "qd"), ("T",)),
    "potential": (("q",), ("V",)),
    "momentum": (("q", "qd"), ("p",)),
    "hamiltonian": (("q", "p", "u"), ("qdot", "pdot")),
    "ode": (("x", "u"), ("xdot",)),
}

_OPTS = {"cse": True}


def safe_name(name: str) -> str:
    """A valid C identifier made from a spec name."""
    out = re.sub(r"\W", "_", name)
    if not out or out[0].isdigit():
        out = "m_" + out
    return out


def spd_solve_function(n: int, k: int, name: str) -> ca.Function:
    """X = M^-1 B for symmetric positive-definite M (n x n), B (n x k), by a Cholesky factor
    written out in SX (no pivoting, no symbolic inverse)."""
    M = ca.SX.sym("M", n, n)
    B = ca.SX.sym("B", n, k)
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        s = M[j, j]
        for c in range(j):
            s = s - L[j][c] * L[j][c]
        L[j][j] = ca.sqrt(s)
        inv = 1.0 / L[j][j]
        for i in range(j + 1, n):
            s = M[i, j]
            for c in range(j):
                s = s - L[i][c] * L[j][c]
            L[i][j] = s * inv
    cols = []
    for col in range(k):
        y = [None] * n
        for i in range(n):
            s = B[i, col]
            for c in range(i):
                s = s - L[i][c] * y[c]
            y[i] = s / L[i][i]
        x = [None] * n
        for i in reversed(range(n)):
            s = y[i]
            for c in range(i + 1, n):
                s = s - L[c][i] * x[c]
            x[i] = s / L[i][i]
        cols.append(ca.vertcat(*x))
    X = ca.horzcat(*cols) if cols else ca.SX(n, 0)
    return ca.Function(name, [M, B], [X], ["M", "B"], ["X"], _OPTS)


class _Builder:
    """Builds the MX graphs of the public Functions from a :class:`SymbolicModel`."""

    def __init__(self, model: SymbolicModel):
        self.model = model
        self.prefix = safe_name(model.spec.name)
        self.n, self.m = model.n, model.m
        self._parts: dict[tuple, ca.Function] = {}
        self._built: dict[str, ca.Function] = {}
        self._solvers: dict[int, ca.Function] = {}

    def part_function(self, part: Part, keys: tuple[str, ...]) -> ca.Function:
        """The part's terms ``keys`` as a Function of (q, qd); a plate density is mapped over
        its quadrature nodes and summed. Cached, so that Functions needing the same terms share
        one dependency (generated once in a C file)."""
        cache_key = (part.name, keys)
        if cache_key not in self._parts:
            self._parts[cache_key] = self._part_function(part, keys)
        return self._parts[cache_key]

    def _part_function(self, part: Part, keys: tuple[str, ...]) -> ca.Function:
        mdl = self.model
        name = f"{self.prefix}_{part.name}_{'_'.join(keys)}"
        if part.hoisted is not None and part.hoisted.supports(keys):
            return self.hoisted_function(part, keys, name)
        exprs = [getattr(part.terms, k) for k in keys]
        if part.nodes is None:
            return ca.Function(name, [mdl.q, mdl.qd], exprs, ["q", "qd"], list(keys), _OPTS)
        w = ca.SX.sym("w")
        density = ca.Function(name + "_density", [mdl.q, mdl.qd, mdl.zeta, w],
                              [w * e for e in exprs], ["q", "qd", "zeta", "w"], list(keys),
                              _OPTS)
        N = len(part.nodes)
        mapped = density.map(name + "_map", "serial", N, [0, 1], list(range(len(keys))))
        zeta = ca.DM(part.nodes).T
        weights = ca.DM(part.weights).T
        q, qd = ca.MX.sym("q", self.n), ca.MX.sym("qd", self.n)
        outs = mapped.call([q, qd, zeta, weights])
        return ca.Function(name, [q, qd], outs, ["q", "qd"], list(keys))

    def hoisted_function(self, part: Part, keys: tuple[str, ...], name: str) -> ca.Function:
        """Like :meth:`part_function` for a spatial segment, with the base-frame kinematics
        as inputs (computed once by :meth:`chain`) and only the per-node density mapped
        (:class:`~symbolic.derivation._hoisted.HoistedPlate`): (q, qd, base...) -> terms."""
        hp, n = part.hoisted, self.n
        k = hp.k
        q, qd = ca.MX.sym("q", n), ca.MX.sym("qd", n)
        base = [ca.MX.sym(f, *shape) for f, shape in kin.base_shapes(k).items()] if k else []
        nodes = [q[k : k + 3], qd[k : k + 3], ca.DM(part.nodes).T, ca.DM(part.weights).T]
        N = len(part.nodes)
        if part.moments is not None and part.moments.supports(keys):
            # integrate the local moments only, then assemble with the base frame once
            density = part.moments.density_function(keys, name + "_moments")
            mapped = density.map(name + "_map", "serial", N, [0, 1],
                                 list(range(density.n_out())))
            moments = mapped.call(nodes)
            blocks = part.moments.assemble_function(keys, name + "_assemble").call(
                [*moments, *base])
        else:
            density = hp.density_function(keys, name + "_density")
            reduce_in = [j for j in range(density.n_in()) if j not in (2, 3)]
            mapped = density.map(name + "_map", "serial", N, reduce_in, list(range(len(keys))))
            blocks = mapped.call([*nodes, *base])
        rest = n - k - 3
        outs = []
        for key, b in zip(keys, blocks, strict=True):
            if rest and key in ("M", "C"):
                b = ca.diagcat(b, ca.MX(rest, rest))
            elif rest and key not in ("V", "T"):
                b = ca.vertcat(b, ca.MX(rest, 1))
            outs.append(b)
        in_names = ["q", "qd"] + (list(kin.BASE_FIELDS) if k else [])
        return ca.Function(name, [q, qd, *base], outs, in_names, list(keys))

    #: fields of the frame after the last segment (only the tip-wrench matrix uses it)
    TIP_FIELDS = ("Rb", "dtb", "Jwb")

    def step(self, i: int) -> ca.Function:
        spec = self.model.spec
        last = i == len(spec.segments) - 1
        key = f"step{i}"
        if key not in self._built:
            fields = self.TIP_FIELDS if last else kin.BASE_FIELDS
            name = f"{self.prefix}_tip" if last else f"{self.prefix}_base{i + 2}"
            self._built[key] = kin.base_step_function(spec, i, name, fields)
        return self._built[key]

    def chain(self, q, qd, upto: int) -> list[list]:
        """Base-frame quantities of segments 0..upto-1 (0 = the world frame, no quantities)
        and, if ``upto`` exceeds the segment count, of the frame after the last segment
        (only :data:`TIP_FIELDS` of it, the rest None)."""
        bases: list[list] = [[]]
        for i in range(upto - 1):
            step = self.step(i)
            outs = step.call([q[3 * i : 3 * i + 3], qd[3 * i : 3 * i + 3], *bases[i]])
            got = dict(zip([n[: -len("_next")] for n in step.name_out()], outs, strict=True))
            bases.append([got.get(f) for f in kin.BASE_FIELDS])
        return bases

    def terms(self, keys: tuple[str, ...], q, qd, tag: str = "", bases=None) -> list:
        """Sum over parts of the terms ``keys`` at MX (q, qd), densified (``bases``: the
        :meth:`chain` at (q, qd) if already computed)."""
        totals = [None] * len(keys)
        if qd is None:  # a function of q only
            qd = ca.MX.zeros(self.n, 1)
        for part in self.model.parts:
            wanted = tuple(k for k in keys if not _structurally_zero(part, k))
            if not wanted:
                continue
            fn = self.part_function(part, wanted)
            if part.hoisted is not None and part.hoisted.supports(wanted):
                if bases is None:
                    bases = self.chain(q, qd, len(self.model.spec.segments))
                outs = fn.call([q, qd, *bases[part.hoisted.i]])
            else:
                outs = fn.call([q, qd])
            for k, val in zip(wanted, outs, strict=True):
                i = keys.index(k)
                totals[i] = val if totals[i] is None else totals[i] + val
        shapes = {"M": (self.n, self.n), "C": (self.n, self.n), "V": (1, 1), "T": (1, 1)}
        out = []
        for k, val in zip(keys, totals, strict=True):
            shape = shapes.get(k, (self.n, 1))
            out.append(ca.densify(val) if val is not None else ca.MX.zeros(*shape))
        return out

    def solver(self, k: int, tag: str = "") -> ca.Function:
        if k not in self._solvers:
            self._solvers[k] = spd_solve_function(self.n, k, f"{self.prefix}_solve{k}")
        return self._solvers[k]

    def A_function(self) -> ca.Function:
        if "A_expr" not in self._built:
            self._built["A_expr"] = self._A_function()
        return self._built["A_expr"]

    def uses_chain_for_A(self) -> bool:
        mdl = self.model
        return mdl.spec.actuation == "tip-wrench" and mdl.hoist

    def tip_wrench_A(self, bases) -> ca.MX:
        """A from the frames after each segment (``bases`` of :meth:`chain` with one more
        step than segments): R_tip = R_b Rz^T, so the tip's body angular Jacobian is Rz Jw_b
        and R_tip^T Jv has the third row of R_b^T dt_b (see :func:`eom.tip_wrench_matrix`)."""
        spec, n = self.model.spec, self.n
        Rz = ca.DM(kin.rot_z(math.pi / spec.actuators_per_segment))
        cols = []
        for i in range(len(spec.segments)):
            b = dict(zip(kin.BASE_FIELDS, bases[i + 1], strict=True))
            Jb = Rz @ b["Jwb"]
            Jvb = (b["Rb"].T @ b["dtb"])[2, :]
            block = ca.horzcat(-Jb[0, :].T, -Jb[1, :].T, Jvb.T)
            pad = n - 3 * (i + 1)
            cols.append(ca.vertcat(block, ca.MX(pad, 3)) if pad else block)
        return ca.densify(ca.horzcat(*cols))

    def _A_function(self) -> ca.Function:
        mdl = self.model
        if self.uses_chain_for_A():
            q = ca.MX.sym("q", self.n)
            bases = self.chain(q, ca.MX.zeros(self.n, 1), len(mdl.spec.segments) + 1)
            return ca.Function(f"{self.prefix}_A_expr", [q], [self.tip_wrench_A(bases)], ["q"],
                               ["A"])
        A = mdl.A
        # A never depends on qd (the tip-wrench Jacobian is linear in qd); substitute 0 anyway.
        A = ca.substitute(A, mdl.qd, ca.SX.zeros(self.n))
        return ca.Function(f"{self.prefix}_A_expr", [mdl.q], [ca.densify(A)], ["q"], ["A"],
                           _OPTS)

    def build(self, key: str) -> ca.Function:
        if key not in self._built:
            self._built[key] = self._build(key)
        return self._built[key]

    def _build(self, key: str) -> ca.Function:
        n, m = self.n, self.m
        q = ca.MX.sym("q", n)
        qd = ca.MX.sym("qd", n)
        u = ca.MX.sym("u", m)
        D = ca.MX(self.model.D)
        name = f"{self.prefix}_{key}"
        if key == "M":
            (M,) = self.terms(("M",), q, None, key)
            outs, ins = [M], [q]
        elif key == "M_inv":
            (M,) = self.terms(("M",), q, None, key)
            outs, ins = [self.solver(n, key)(M, ca.MX.eye(n))], [q]
        elif key == "G":
            outs, ins = self.terms(("G",), q, None, key), [q]
        elif key == "D":
            outs, ins = [ca.densify(D)], [q]
        elif key == "A":
            outs, ins = [self.A_function()(q)], [q]
        elif key in ("C", "Cqd"):
            outs, ins = self.terms((key,), q, qd, key), [q, qd]
        elif key == "forward":
            bases = None
            if self.uses_chain_for_A():  # one pass over the segments for A and the terms
                bases = self.chain(q, qd, len(self.model.spec.segments) + 1)
            M, G, Cqd = self.terms(("M", "G", "Cqd"), q, qd, key, bases)
            A = None
            if m:
                A = self.tip_wrench_A(bases) if bases is not None else self.A_function()(q)
            qdd = eom.forward_dynamics(M, Cqd, G, D, qd, A, u, self.solver(1, key))
            outs, ins = [qdd], [q, qd, u]
        elif key == "ode":
            x = ca.MX.sym("x", 2 * n)
            qdd = self.build("forward")(x[:n], x[n:], u)
            outs, ins = [ca.vertcat(x[n:], qdd)], [x, u]
        elif key == "inverse":
            qdd = ca.MX.sym("qdd", n)
            M, G, Cqd = self.terms(("M", "G", "Cqd"), q, qd, key)
            outs, ins = [eom.inverse_dynamics(M, qdd, Cqd, G, D, qd)], [q, qd, qdd]
        elif key in ("energy", "kinetic", "potential"):
            T, V = self.terms(("T", "V"), q, None if key == "potential" else qd, key)
            val = {"energy": T + V, "kinetic": T, "potential": V}[key]
            outs, ins = [val], ([q] if key == "potential" else [q, qd])
        elif key == "momentum":
            (M,) = self.terms(("M",), q, None, key)
            outs, ins = [M @ qd], [q, qd]
        elif key == "hamiltonian":
            p = ca.MX.sym("p", n)
            M, G = self.terms(("M", "G"), q, None, key)
            qdot, pdot = eom.hamiltonian_field(
                M, p, G, D, self.A_function()(q) if m else None, u, self.solver(1, key),
                lambda v: self.terms(("dTdq",), q, v, key + "_dTdq")[0])
            outs, ins = [qdot, pdot], [q, p, u]
        else:
            raise KeyError(key)
        in_names, out_names = SIGNATURES[key]
        return ca.Function(name, ins, outs, list(in_names), list(out_names), _OPTS)


def _structurally_zero(part: Part, key: str) -> bool:
    """Terms a closed-form part does not contribute (skips building empty Functions)."""
    terms = part.terms
    if part.nodes is not None:
        return False
    expr_zero = {
        "M": lambda: terms.M.nnz() == 0,
        "T": lambda: terms.M.nnz() == 0,
        "C": lambda: not ca.depends_on(terms.M, terms.q),
        "Cqd": lambda: terms.Cqd.nnz() == 0,
        "dTdq": lambda: not ca.depends_on(terms.M, terms.q),
    }
    check = expr_zero.get(key)
    return bool(check()) if check else False


def functions_of(model: SymbolicModel) -> dict[str, ca.Function]:
    """The Functions of an already derived model (:func:`symbolic.derivation._eom.derive`), keyed as
    in :data:`SIGNATURES`: wraps its expressions, derives nothing again."""
    builder = _Builder(model)
    return {key: builder.build(key) for key in SIGNATURES}


@lru_cache(maxsize=32)
def _functions(spec: ModelSpec, order: int) -> dict[str, ca.Function]:
    return functions_of(derive(spec, order))


def functions(model: str | Path | ModelSpec, order: int | None = None) -> dict[str, ca.Function]:
    """All Functions of a model (a :class:`ModelSpec`, a preset name or a spec path), keyed as
    in :data:`SIGNATURES`; cached per spec value. ``order`` is the Gauss-Legendre order of the
    zeta integrals (default :data:`symbolic.derivation._energies.DEFAULT_ORDER`)."""
    spec = load_spec(model)
    return dict(_functions(spec, DEFAULT_ORDER if order is None else check_order(order)))


def function_sizes(fns: dict[str, ca.Function]) -> dict[str, int]:
    """Number of elementary operations of each Function after expanding it to SX (a measure
    of generated-code size), or -1 where it cannot be expanded."""
    out = {}
    for key, f in fns.items():
        try:
            out[key] = int(f.expand().n_nodes()) if f.is_a("MXFunction") else int(f.n_nodes())
        except RuntimeError:
            out[key] = -1
    return out


__all__ = [
    "SIGNATURES",
    "function_sizes",
    "functions",
    "functions_of",
    "safe_name",
    "spd_solve_function",
]
