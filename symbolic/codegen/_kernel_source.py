"""C source of the batched kernels (:mod:`.kernel`): one state's straight-line code from CasADi's
SX instruction list inside a loop over a batch of states, and a fixed-step RK4 integrator over
many trajectories in the same C. :mod:`.kernel` compiles, caches and loads it."""

from __future__ import annotations

import math

import casadi as ca

from softpinn.errors import UserError

#: batches are padded to a multiple of this many states (8 doubles: one AVX-512 vector, two
#: AVX2 ones), rows start 64-byte aligned
WIDTH = 8

_UNARY = {
    ca.OP_ASSIGN: "{0}", ca.OP_NEG: "(-{0})", ca.OP_EXP: "exp({0})", ca.OP_LOG: "log({0})",
    ca.OP_SQRT: "sqrt({0})", ca.OP_SQ: "({0}*{0})", ca.OP_TWICE: "({0}+{0})",
    ca.OP_SIN: "sin({0})",
    # cos is even, so cos(x + 0.) == cos(x) bit for bit; the distinct argument keeps gcc from
    # merging sin(x) and cos(x) into one complex sincos call, which it cannot vectorise
    ca.OP_COS: "cos({0}+0.)",
    ca.OP_TAN: "tan({0})", ca.OP_ASIN: "asin({0})", ca.OP_ACOS: "acos({0})",
    ca.OP_ATAN: "atan({0})", ca.OP_FLOOR: "floor({0})", ca.OP_CEIL: "ceil({0})",
    ca.OP_FABS: "fabs({0})", ca.OP_SIGN: "(({0})<0 ? -1. : (({0})>0 ? 1. : ({0})))",
    ca.OP_ERF: "erf({0})", ca.OP_INV: "(1./{0})", ca.OP_SINH: "sinh({0})",
    ca.OP_COSH: "cosh({0})", ca.OP_TANH: "tanh({0})", ca.OP_ASINH: "asinh({0})",
    ca.OP_ACOSH: "acosh({0})", ca.OP_ATANH: "atanh({0})", ca.OP_LOG1P: "log1p({0})",
    ca.OP_EXPM1: "expm1({0})", ca.OP_NOT: "((double)(!{0}))",
}
_BINARY = {
    ca.OP_ADD: "({0}+{1})", ca.OP_SUB: "({0}-{1})", ca.OP_MUL: "({0}*{1})",
    ca.OP_DIV: "({0}/{1})", ca.OP_POW: "pow({0},{1})", ca.OP_CONSTPOW: "pow({0},{1})",
    ca.OP_ATAN2: "atan2({0},{1})", ca.OP_FMIN: "fmin({0},{1})", ca.OP_FMAX: "fmax({0},{1})",
    ca.OP_FMOD: "fmod({0},{1})", ca.OP_REMAINDER: "remainder({0},{1})",
    ca.OP_COPYSIGN: "copysign({0},{1})", ca.OP_HYPOT: "hypot({0},{1})",
    ca.OP_LT: "((double)({0}<{1}))", ca.OP_LE: "((double)({0}<={1}))",
    ca.OP_EQ: "((double)({0}=={1}))", ca.OP_NE: "((double)({0}!={1}))",
    ca.OP_AND: "((double)({0}&&{1}))", ca.OP_OR: "((double)({0}||{1}))",
    ca.OP_IF_ELSE_ZERO: "({0}?{1}:0.)",
}
_OP_NAMES = {getattr(ca, a): a for a in dir(ca) if a.startswith("OP_")}

#: vector variants in every libmvec since glibc 2.22 (x86_64)
HEADER = """\
#include <math.h>
/* callers pass 64-byte aligned rows and a batch that is a multiple of WIDTH: every state then
   runs the same vector code (no peeled or scalar remainder), so a state's bits do not depend on
   its place in the batch */
#ifdef __GNUC__
#define SOFTPINN_ALIGNED(p) __builtin_assume_aligned((p), 64)
#else
#define SOFTPINN_ALIGNED(p) (p)
#endif
#ifdef SOFTPINN_MVEC
double sin(double) __attribute__((simd("notinbranch")));
double cos(double) __attribute__((simd("notinbranch")));
double exp(double) __attribute__((simd("notinbranch")));
double log(double) __attribute__((simd("notinbranch")));
double pow(double, double) __attribute__((simd("notinbranch")));
#endif
"""


class KernelError(UserError):
    """A CasADi Function that has no batched C kernel (an instruction without a C form)."""


def expand(f: ca.Function) -> ca.Function:
    """``f`` as an SX Function (``Function.expand`` for MX)."""
    if f.is_a("MXFunction"):
        try:
            f = f.expand()
        except RuntimeError as err:
            raise KernelError(f"{f.name()}: cannot expand to SX ({err})") from err
    if not f.is_a("SXFunction"):
        raise KernelError(f"{f.name()}: expected an SX or MX Function, got {f.class_name()}")
    return f


def dense(f: ca.Function) -> ca.Function:
    """``f`` with dense outputs (a zero signal's output has no nonzeros)."""
    if all(f.sparsity_out(k).is_dense() for k in range(f.n_out())):
        return f
    args = f.sx_in()
    outs = f.call(args)
    return ca.Function(f.name(), args, [ca.densify(o) for o in outs], f.name_in(), f.name_out())


def _literal(c: float) -> str:
    if math.isnan(c):
        return "(0./0.)"
    if math.isinf(c):
        return "(1./0.)" if c > 0 else "(-1./0.)"
    return float(c).hex()


def shared_denominators(f: ca.Function) -> set[tuple[int, int]]:
    """The divisors of ``f``'s SX instruction list that divide more than once: (work slot,
    how many times the slot had been written when it divides), work slots being reused."""
    writes: dict[int, int] = {}
    uses: dict[tuple[int, int], int] = {}
    for k in range(f.n_instructions()):
        op, i, o = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_DIV:
            key = (i[1], writes.get(i[1], 0))
            uses[key] = uses.get(key, 0) + 1
        if op != ca.OP_OUTPUT:
            writes[o[0]] = writes.get(o[0], 0) + 1
    return {key for key, count in uses.items() if count > 1}


def kernel_source(f: ca.Function, name: str) -> str:
    """C source of ``void name(long n, long ld, const double* const* arg, double* const* res)``
    evaluating the SX Function ``f`` at ``n`` states: input k's nonzero j of state i is
    ``arg[k][j*ld + i]``, output k's nonzero j goes to ``res[k][j*ld + i]`` (no header).

    A divisor that divides several times is inverted once (``d = 1./w``) and its divisions
    become products ``x*d``: a vector division costs several times a product, and CasADi's
    instruction lists divide by the same few values again and again (the planar PCC arm of one
    segment: 205 divisions by 32 values per state; task5: 157 by 72). ``x*(1/w)`` is
    within an ulp of ``x/w``; the kernels stay equal to CasADi's evaluation to ~1e-14 relative
    per state (tests/test_batched_kernels.py)."""
    f = expand(f)
    for k in range(f.n_in()):
        if not f.sparsity_in(k).is_dense():
            raise KernelError(f"{f.name()}: input {f.name_in(k)} is sparse (kernels take dense "
                              "inputs)")
    shared = shared_denominators(f)
    lines = [f"void {name}(long n, long ld, const double* const* arg, double* const* res) {{"]
    lines += [f"  const double* restrict a{k} = SOFTPINN_ALIGNED(arg[{k}]);"
              for k in range(f.n_in())]
    lines += [f"  double* restrict r{k} = SOFTPINN_ALIGNED(res[{k}]);" for k in range(f.n_out())]
    lines += ["  #pragma omp simd", "  for (long i = 0; i < n; ++i) {"]
    nw = f.sz_w()
    if nw:
        lines.append("    double " + ", ".join(f"w{j}" for j in range(nw)) + ";")
    if shared:
        lines.append("    double " + ", ".join(f"d{j}" for j in range(len(shared))) + ";")
    inverse: dict[tuple[int, int], str] = {}
    writes: dict[int, int] = {}
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        i, o = f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_CONST:
            rhs = _literal(f.instruction_constant(k))
        elif op == ca.OP_INPUT:
            rhs = f"a{i[0]}[{i[1]}*ld+i]"
        elif op == ca.OP_OUTPUT:
            lines.append(f"    r{o[0]}[{o[1]}*ld+i] = w{i[0]};")
            continue
        elif op == ca.OP_DIV and (i[1], writes.get(i[1], 0)) in shared:
            key = (i[1], writes.get(i[1], 0))
            if key not in inverse:
                inverse[key] = f"d{len(inverse)}"
                lines.append(f"    {inverse[key]} = 1./w{i[1]};")
            rhs = f"(w{i[0]}*{inverse[key]})"
        elif op in _BINARY:
            rhs = _BINARY[op].format(f"w{i[0]}", f"w{i[1]}")
        elif op in _UNARY:
            rhs = _UNARY[op].format(f"w{i[0]}")
        else:
            raise KernelError(f"{f.name()}: instruction {k} is CasADi's "
                              f"{_OP_NAMES.get(op, op)}, which has no batched C kernel")
        lines.append(f"    w{o[0]} = {rhs};")
        writes[o[0]] = writes.get(o[0], 0) + 1
    lines += ["  }", "}", ""]
    return "\n".join(lines)


def cuda_source(f: ca.Function, name: str) -> str:
    """The kernel of :func:`kernel_source` as CUDA C++: ``extern "C" __global__ void
    name(long n, long ld, const double* const* arg, double* const* res)``, one thread per
    state (i = blockIdx.x * blockDim.x + threadIdx.x), the same straight-line code and layout
    (input k's nonzero j of state i at ``arg[k][j*ld + i]``: consecutive threads read
    consecutive addresses). For a GPU machine without CasADi: compile it there with NVRTC (e.g.
    ``cupy.RawModule``; ``benchmarks/bench_gpu.py``)."""
    src = kernel_source(f, name)
    src = src.replace(f"void {name}(", f'extern "C" __global__ void {name}(', 1)
    src = src.replace("const double* restrict", "const double* __restrict__")
    src = src.replace("double* restrict", "double* __restrict__")
    src = src.replace("SOFTPINN_ALIGNED(", "(")
    loop = "  #pragma omp simd\n  for (long i = 0; i < n; ++i) {"
    if loop not in src:  # pragma: no cover - kernel_source's loop changed
        raise KernelError(f"{f.name()}: no state loop to map onto threads")
    return src.replace(loop, "  long i = (long)blockIdx.x * blockDim.x + threadIdx.x;\n"
                             "  if (i < n) {", 1)


#: RK4 over many trajectories, in blocks of BLOCK lanes (struct of arrays inside a block); the
#: arithmetic is that of :mod:`softpinn.bridge.exact.simulate`: stage i evaluates
#: f(x + (c_i dt) k_{i-1}, t + c_i dt), acc += b_i k_i, x += dt acc; t = s / rate + j dt.
_RK4 = """
#define BLOCK 64
#ifdef __GNUC__
#define ALIGN64 __attribute__((aligned(64)))
#else
#define ALIGN64
#endif
void softpinn_rk4(long K, long nx, long nu, long np, const double* x0, const double* p,
                  long samples, long sub, double dt, double rate, double* out) {
  static const double c[4] = {0.0, 0.5, 0.5, 1.0};
  static const double b[4] = {1.0/6.0, 2.0/6.0, 2.0/6.0, 1.0/6.0};
  static const long W = WIDTH;
  double x[NX * BLOCK] ALIGN64, xs[NX * BLOCK] ALIGN64, k[NX * BLOCK] ALIGN64;
  double acc[NX * BLOCK] ALIGN64, tt[BLOCK] ALIGN64;
  double u[(NU > 0 ? NU : 1) * BLOCK] ALIGN64, pp[(NP > 0 ? NP : 1) * BLOCK] ALIGN64;
  for (long r = 0; r < NX * BLOCK; ++r) { x[r] = 0.0; xs[r] = 0.0; k[r] = 0.0; acc[r] = 0.0; }
  for (long r = 0; r < (NU > 0 ? NU : 1) * BLOCK; ++r) u[r] = 0.0;
  for (long r = 0; r < (NP > 0 ? NP : 1) * BLOCK; ++r) pp[r] = 0.0;
  for (long k0 = 0; k0 < K; k0 += BLOCK) {
    long nb = K - k0 < BLOCK ? K - k0 : BLOCK;
    long nv = (nb + W - 1) / W * W;  /* whole vectors: the lanes past nb hold finite stale data */
    for (long r = 0; r < NX; ++r) for (long i = 0; i < nb; ++i) {
      x[r*BLOCK+i] = x0[r*K+k0+i]; out[r*K+k0+i] = x[r*BLOCK+i];
    }
    for (long r = 0; r < NP; ++r) for (long i = 0; i < nb; ++i) pp[r*BLOCK+i] = p[r*K+k0+i];
    const double* sarg[2] = {tt, pp};
    double* sres[1] = {u};
    const double* oarg[2] = {xs, u};
    double* ores[1] = {k};
    for (long s = 0; s + 1 < samples; ++s) {
      double t0 = (double)s / rate;
      for (long j = 0; j < sub; ++j) {
        double t = t0 + (double)j * dt;
        for (long r = 0; r < NX * BLOCK; ++r) { k[r] = 0.0; acc[r] = 0.0; }
        for (int st = 0; st < 4; ++st) {
          double h = c[st] * dt, ts = t + c[st] * dt;
          for (long r = 0; r < NX * BLOCK; ++r) xs[r] = x[r] + h * k[r];
          for (long i = 0; i < BLOCK; ++i) tt[i] = ts;
          if (NU > 0) SIGNAL(nv, BLOCK, sarg, sres);
          ODE(nv, BLOCK, oarg, ores);
          for (long r = 0; r < NX * BLOCK; ++r) acc[r] = acc[r] + b[st] * k[r];
        }
        for (long r = 0; r < NX * BLOCK; ++r) x[r] = x[r] + dt * acc[r];
      }
      double* o = out + (s + 1) * NX * K;
      for (long r = 0; r < NX; ++r) for (long i = 0; i < nb; ++i) o[r*K+k0+i] = x[r*BLOCK+i];
    }
  }
}
"""


def rk4_source(ode: ca.Function, signal: ca.Function) -> str:
    """C source of the kernels ``softpinn_ode`` (``ode(x, u)``), ``softpinn_signal``
    (``u(t, p)``) and ``softpinn_rk4(K, nx, nu, np, x0 (nx, K), p (np, K), samples, sub, dt,
    rate, out (samples, nx, K))``."""
    ode, signal = dense(expand(ode)), dense(expand(signal))
    nx, nu = ode.nnz_in(0), ode.nnz_in(1) if ode.n_in() > 1 else 0
    npar = signal.nnz_in(1) if signal.n_in() > 1 else 0
    if ode.n_in() != 2 or ode.nnz_out(0) != nx or signal.nnz_out(0) != nu or \
            signal.nnz_in(0) != 1:
        raise KernelError(f"rk4: expected ode(x[{nx}], u) -> xdot[{nx}] and u(t, p) -> u, got "
                          f"{ode.name()} and {signal.name()}")
    return "".join([
        kernel_source(ode, "softpinn_ode"),
        kernel_source(signal, "softpinn_signal"),
        f"#define NX {nx}\n#define NU {nu}\n#define NP {npar}\n#define WIDTH {WIDTH}\n",
        "#define ODE softpinn_ode\n#define SIGNAL softpinn_signal\n",
        _RK4,
    ])
