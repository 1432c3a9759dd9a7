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
    ca.OP_IF_ELSE_ZERO: "softpinn_if({0},{1})",
}
_OP_NAMES = {getattr(ca, a): a for a in dir(ca) if a.startswith("OP_")}

#: the most instructions for which :func:`kernel_source` writes a kernel without a scalar
#: remainder loop and with the branchless ``softpinn_if`` (compile time, see there)
LARGE = 25_000

#: instructions that become calls to the math library (vector variants from libmvec where it
#: has them): every vector register is caller-saved, so live values are stored around each call
_CALLS = {ca.OP_SIN, ca.OP_COS, ca.OP_TAN, ca.OP_EXP, ca.OP_LOG, ca.OP_POW, ca.OP_CONSTPOW,
          ca.OP_ASIN, ca.OP_ACOS, ca.OP_ATAN, ca.OP_ATAN2, ca.OP_SINH, ca.OP_COSH, ca.OP_TANH,
          ca.OP_ASINH, ca.OP_ACOSH, ca.OP_ATANH, ca.OP_ERF, ca.OP_LOG1P, ca.OP_EXPM1,
          ca.OP_FMOD, ca.OP_REMAINDER, ca.OP_HYPOT}

#: vector variants in every libmvec since glibc 2.22 (x86_64); softpinn_if is CasADi's
#: OP_IF_ELSE_ZERO (c ? x : 0, c NaN counting as true) without a branch, for kernels up to
#: :data:`LARGE` instructions: gcc turns a ``?:`` into control flow, and its jump threading
#: then duplicates code between an if_else's two complementary conditions (task5: 94 divisions,
#: 50 square roots and 33 sines per state instead of 72, 28 and 22), while the bit mask
#: compiles to one masked move
HEADER = """\
#include <math.h>
#include <string.h>
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
static inline double softpinn_if(double c, double x) {
  unsigned long long b;
  memcpy(&b, &x, sizeof b);
  b &= -(unsigned long long)(c != 0.);
  memcpy(&x, &b, sizeof b);
  return x;
}
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


def _program(f: ca.Function) -> tuple[list[int], list[list[int]]]:
    """``f``'s SX instructions as a single-assignment program: each instruction's operation and
    the instructions whose results it reads (CasADi reuses work slots; here every result has
    its own value)."""
    ops, srcs, current = [], [], {}
    for k in range(f.n_instructions()):
        op, i, o = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op in (ca.OP_CONST, ca.OP_INPUT):
            src = []
        elif op in _BINARY:
            src = [current[i[0]], current[i[1]]]
        else:  # unary, OP_OUTPUT, and the unknown ones kernel_source rejects
            src = [current[i[0]]] if i and i[0] in current else []
        ops.append(op)
        srcs.append(src)
        if op != ca.OP_OUTPUT:
            current[o[0]] = k
    return ops, srcs


def shared_denominators(f: ca.Function) -> set[int]:
    """The instructions of ``f``'s SX list whose result divides more than once."""
    ops, srcs = _program(expand(f))
    uses: dict[int, int] = {}
    for op, src in zip(ops, srcs, strict=True):
        if op == ca.OP_DIV:
            uses[src[1]] = uses.get(src[1], 0) + 1
    return {k for k, count in uses.items() if count > 1}


def _order(ops: list[int], srcs: list[list[int]]) -> list[int]:
    """The instructions in the order the kernel computes them, for fewer values stored and
    reloaded (task5 holds ~370 values live on average in CasADi's order, against 32 vector
    registers):

    1. depth first from each output, of an instruction's operands the one that needs more
       registers first (Sethi and Ullman's labels, counted as if the instruction graph were a
       tree; ties in CasADi's order);
    2. of that order, the math-library calls and everything they depend on first. A call
       clobbers every vector register, so every live value costs a store and a load around
       it; early in the program few values are live (task5: 278 of 10,013 instructions feed
       its 44 sines and cosines).

    Measured against CasADi's order on one core (AVX-512, gcc 12): step 2 ~5% faster per state
    for task5 and ~10% for the planar arm of one segment, step 1 another ~2% (task5) to ~10%
    (planar, two segments). The instructions are the same, so are the results."""
    n = len(ops)
    need = [1] * n
    for k in range(n):
        if ops[k] == ca.OP_CONST:
            need[k] = 0
        elif len(srcs[k]) == 2:
            a, b = need[srcs[k][0]], need[srcs[k][1]]
            need[k] = a + 1 if a == b else max(a, b)
        elif srcs[k]:
            need[k] = need[srcs[k][0]]
    done, seq = [False] * n, []
    for root in range(n):
        if ops[root] != ca.OP_OUTPUT:
            continue
        stack = [(root, False)]
        while stack:
            k, expanded = stack.pop()
            if done[k]:
                continue
            if expanded:
                done[k] = True
                seq.append(k)
                continue
            stack.append((k, True))
            operands = sorted(set(srcs[k]), key=lambda j: (-need[j], j))
            stack.extend((j, False) for j in reversed(operands) if not done[j])
    seq += [k for k in range(n) if not done[k]]  # feeds no output
    first = [False] * n
    for k in range(n - 1, -1, -1):
        first[k] = first[k] or ops[k] in _CALLS
        if first[k]:
            for j in srcs[k]:
                first[j] = True
    return [k for k in seq if first[k]] + [k for k in seq if not first[k]]


def kernel_source(f: ca.Function, name: str) -> str:
    """C source of ``void name(long n, long ld, const double* const* arg, double* const* res)``
    evaluating the SX Function ``f`` at ``n`` states: input k's nonzero j of state i is
    ``arg[k][j*ld + i]``, output k's nonzero j goes to ``res[k][j*ld + i]`` (no header). ``n``
    is a multiple of :data:`WIDTH` (callers pad the batch).

    Up to :data:`LARGE` instructions the loop runs to ``n`` rounded down to :data:`WIDTH`,
    which tells the compiler so (no scalar remainder loop), and if_else is the branchless
    ``softpinn_if``: half the code, and task5 compiles in ~3.5 s against ~6.5 s. Both leave
    gcc's register allocator a few large basic blocks, on which its full algorithm takes time
    growing faster than the instruction count (gcc 12, 2 cores at 2.6 GHz: 3 spatial segments,
    18,700 instructions, 12 s; 4 segments, 29,000, 22 s; 6 segments, 58,000, 69 s). Above
    :data:`LARGE` the kernel keeps the remainder loop and C's ``?:`` (as before 28 Nov):
    their many blocks put gcc into its fast allocation (``max_reg_num * blocks >= 2^26``):
    4 segments 6 s, 6 segments 11 s, and 10-15% slower code than the full allocation.

    Every instruction's result is its own variable ``t<k>``, declared where it is computed,
    in :func:`_order`'s order (gcc's own form is single assignment: reusing variables as
    CasADi's work vector does, in the same order, compiles as fast and runs as fast). A divisor
    that divides several times is inverted once (``d<k> = 1./t<k>``) and its divisions become
    products ``x*d<k>``: a vector division costs several times a product, and CasADi's
    instruction lists divide by the same few values again and again (the planar PCC arm of one
    segment: 205 divisions by 32 values per state; task5: 157 by 72). ``x*(1/w)`` is within an
    ulp of ``x/w``; the kernels stay equal to CasADi's evaluation to ~1e-14 relative per state
    (tests/test_batched_kernels.py)."""
    f = expand(f)
    for k in range(f.n_in()):
        if not f.sparsity_in(k).is_dense():
            raise KernelError(f"{f.name()}: input {f.name_in(k)} is sparse (kernels take dense "
                              "inputs)")
    ops, srcs = _program(f)
    for k, op in enumerate(ops):
        if op not in _BINARY and op not in _UNARY and op not in (ca.OP_CONST, ca.OP_INPUT,
                                                                   ca.OP_OUTPUT):
            raise KernelError(f"{f.name()}: instruction {k} is CasADi's "
                              f"{_OP_NAMES.get(op, op)}, which has no batched C kernel")
    shared = shared_denominators(f)
    large = len(ops) > LARGE
    bound = "n" if large else f"(n & -{WIDTH}L)"
    lines = [f"void {name}(long n, long ld, const double* const* arg, double* const* res) {{"]
    lines += [f"  const double* restrict a{k} = SOFTPINN_ALIGNED(arg[{k}]);"
              for k in range(f.n_in())]
    lines += [f"  double* restrict r{k} = SOFTPINN_ALIGNED(res[{k}]);" for k in range(f.n_out())]
    lines += ["  #pragma omp simd", f"  for (long i = 0; i < {bound}; ++i) {{"]
    inverted: set[int] = set()
    for k in _order(ops, srcs):
        op, v = ops[k], [f"t{j}" for j in srcs[k]]
        if op == ca.OP_CONST:
            rhs = _literal(f.instruction_constant(k))
        elif op == ca.OP_INPUT:
            i = f.instruction_input(k)
            rhs = f"a{i[0]}[{i[1]}*ld+i]"
        elif op == ca.OP_OUTPUT:
            o = f.instruction_output(k)
            lines.append(f"    r{o[0]}[{o[1]}*ld+i] = {v[0]};")
            continue
        elif op == ca.OP_DIV and srcs[k][1] in shared:
            d = f"d{srcs[k][1]}"
            if srcs[k][1] not in inverted:
                inverted.add(srcs[k][1])
                lines.append(f"    double {d} = 1./{v[1]};")
            rhs = f"({v[0]}*{d})"
        elif op == ca.OP_IF_ELSE_ZERO and large:
            rhs = f"({v[0]}?{v[1]}:0.)"
        elif op in _BINARY:
            rhs = _BINARY[op].format(*v)
        else:
            rhs = _UNARY[op].format(*v)
        lines.append(f"    double t{k} = {rhs};")
    lines += ["  }", "}", ""]
    return "\n".join(lines)


def cuda_source(f: ca.Function, name: str) -> str:
    """The kernel of :func:`kernel_source` as CUDA C++: ``extern "C" __global__ void
    name(long n, long ld, const double* const* arg, double* const* res)``, one thread per
    state (i = blockIdx.x * blockDim.x + threadIdx.x), the same straight-line code and layout
    (input k's nonzero j of state i at ``arg[k][j*ld + i]``: consecutive threads read
    consecutive addresses); ``softpinn_if`` is a plain ``?:`` there. For a GPU machine without
    CasADi: compile it there with NVRTC (e.g. ``cupy.RawModule``; ``benchmarks/bench_gpu.py``)."""
    src = kernel_source(f, name)
    src = src.replace(f"void {name}(", f'extern "C" __global__ void {name}(', 1)
    src = src.replace("const double* restrict", "const double* __restrict__")
    src = src.replace("double* restrict", "double* __restrict__")
    src = src.replace("SOFTPINN_ALIGNED(", "(")
    for bound in (f"(n & -{WIDTH}L)", "n"):
        loop = f"  #pragma omp simd\n  for (long i = 0; i < {bound}; ++i) {{"
        if loop in src:
            return _CUDA_IF + src.replace(
                loop, "  long i = (long)blockIdx.x * blockDim.x + threadIdx.x;\n  if (i < n) {", 1)
    raise KernelError(f"{f.name()}: no state loop to map onto threads")  # pragma: no cover


_CUDA_IF = ("#ifndef SOFTPINN_IF\n#define SOFTPINN_IF\n"
            "static __device__ __forceinline__ double softpinn_if(double c, double x) {\n"
            "  return c != 0. ? x : 0.;\n}\n#endif\n")


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
