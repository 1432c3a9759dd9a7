"""``softpinn`` subcommands of the symbolic side: models, matrices, derive, simulate.

The commands only map flags onto :mod:`symbolic` functions:

* ``models``: the presets (name, kind, n, m, description);
* ``matrices MODEL --q ...``: M, M^-1, G, D, A, energy (and C, qdd with ``--qd``) at one q;
* ``derive MODEL --out DIR``: C source, shared library, CasADi files and ``summary.json``
  (:func:`symbolic.codegen._codegen.generate`);
* ``simulate MODEL --out FILE.npz``: a data set (:func:`symbolic.simulation._datasets.make_dataset`) with
  the preset's ``[data]`` settings unless flags say otherwise (its command in
  :mod:`bridge.cli.simulate`; checks both share in :mod:`bridge.cli.checks`).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from softpinn.bridge.cli.checks import check_writable, positive, warnings_as_lines
from softpinn.bridge.cli.simulate import cmd_simulate
from softpinn.bridge.exact.serialize import function_data
from softpinn.errors import UserError
from softpinn.symbolic import (
    TrueModel,
    derive,
    dumps,
    find_compiler,
    functions_of,
    generate,
    list_presets,
    load_spec,
    read_derive_summary,
)

SIGNALS = ("zero", "sinusoid", "multisine", "step", "chirp")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "models",
        help="list the model presets",
        description="List the model presets (name, kind, n, m, description).",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_models)

    p = subparsers.add_parser(
        "matrices",
        help="M, M^-1, G, D, A, energy (and C, qdd) of a model at one state",
        description="Evaluate the true matrices of a model (a preset name or a spec .toml) at q "
        "(and qd, u). Matrices are printed as nested row lists with --json.",
    )
    p.add_argument(
        "model", metavar="MODEL", help="preset name (see 'softpinn models') or spec file"
    )
    p.add_argument(
        "--q",
        type=float,
        nargs="+",
        required=True,
        metavar="Q",
        help="generalized coordinates (n values)",
    )
    p.add_argument(
        "--qd",
        type=float,
        nargs="+",
        metavar="V",
        help="generalized velocities (n values); adds C and qdd",
    )
    p.add_argument("--u", type=float, nargs="+", metavar="U", help="inputs (m values; default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_matrices)

    p = subparsers.add_parser(
        "derive",
        help="generate C code, a shared library and CasADi files for a model",
        description="Derive the equations of motion, write the C source, compile a shared "
        "library (gcc -O1), save CasADi serialized functions and summary.json (expression "
        "sizes and timings).",
    )
    p.add_argument("model", metavar="MODEL",
                   help="preset name (see 'softpinn models') or spec file")
    p.add_argument("--out", metavar="DIR", help="output directory (default ./<name>-eom)")
    p.add_argument("--compiler", metavar="CC", help="C compiler (default $CC, gcc, cc)")
    p.add_argument(
        "--timeout",
        type=float,
        default=600.0,
        metavar="S",
        help="compiler timeout in seconds (default 600)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write into a non-empty directory that is not an earlier derive output",
    )
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p.add_argument(
        "--programs", action="store_true",
        help="also write every function as <name>.program.json, its instruction list that "
        "softpinn.learn._sx_replay replays in JAX where CasADi is not installed (a GPU node: "
        "train --known-input DIR/A.program.json there)")
    p.add_argument(
        "--cache",
        metavar="DIR",
        help="also install the library in this compiled-code cache (default $SOFTPINN_CACHE or "
        "~/.cache/softpinn), where 'simulate' finds it",
    )
    p.set_defaults(func=cmd_derive)

    p = subparsers.add_parser(
        "simulate",
        help="simulate trajectories of a model into a dataset file (.npz)",
        description="Simulate trajectories (compiled equations of motion, cvodes or fixed-step "
        "RK4) and write a dataset file. Every setting not given comes from the spec's [data] "
        "table (a preset's: the paper's settings), or, for a spec without one, from defaults "
        "worked out from its physics (printed when used).",
    )
    p.add_argument("model", metavar="MODEL",
                   help="preset name (see 'softpinn models') or spec file")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="dataset file to write")
    p.add_argument("--trajectories", type=int, metavar="K",
                   help="number of trajectories (default: [data]'s train and test counts)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="seconds per trajectory (default: [data] duration)")
    p.add_argument(
        "--settle",
        type=float,
        metavar="S",
        help="seconds simulated before recording starts (default: [data] settle)",
    )
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="output rate [Hz] (default: [data] rate)")
    p.add_argument(
        "--dt", type=float, metavar="S", help="fixed RK4 step [s] (implies --integrator rk4)"
    )
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="farm the trajectories out to Ray: a local instance (no ADDRESS), "
                   "'auto' or HOST:PORT of a cluster (needs softpinn[ray]; the data set is the "
                   "same as without)")
    p.add_argument("--integrator", choices=("cvodes", "rk4", "jax-rk4"),
                   help="cvodes (adaptive, CasADi), rk4 (fixed step, CasADi) or jax-rk4 (fixed "
                   "step, every trajectory at once: batched C kernels of the exact model on "
                   "the CPU, its JAX translation on a GPU or with --no-compile; default: the "
                   "spec's)")
    p.add_argument("--signal", choices=SIGNALS, help="input signal kind (ranges from [data])")
    p.add_argument("--seed", type=int, metavar="S", help="random seed (default: [data] seed)")
    p.add_argument(
        "--noise",
        type=float,
        metavar="SIGMA",
        help="standard deviation of Gaussian measurement noise (default: [data] noise, "
        "else 0)",
    )
    p.add_argument("--equilibria", type=int, default=0, metavar="K",
                   help="also store K stable static equilibria G(q*) = A(q*) u* under constant "
                   "inputs drawn in the signals' input box (eq_q, eq_u, eq_force; labels for "
                   "train --equilibrium-weight; default 0: none)")
    p.add_argument("--rtol", type=float,
                   help="cvodes relative tolerance (default: [data] rtol, else 1e-10)")
    p.add_argument("--atol", type=float,
                   help="cvodes absolute tolerance (default: [data] atol, else 1e-10)")
    p.add_argument(
        "--threads",
        type=int,
        default=2,
        metavar="N",
        help="trajectories integrated at once (default 2)",
    )
    p.add_argument(
        "--no-compile",
        action="store_true",
        help="run the equations in CasADi's virtual machine, no C compiler",
    )
    p.add_argument(
        "--cache",
        metavar="DIR",
        help="compiled-code cache (default $SOFTPINN_CACHE or ~/.cache/softpinn)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_simulate)


# --------------------------------------------------------------------------------------------


def cmd_models(args) -> int:

    rows = []
    for name in list_presets():
        spec = load_spec(name)
        rows.append(
            {
                "name": name,
                "kind": spec.kind,
                "n": spec.n,
                "m": spec.m,
                "description": spec.description,
            }
        )
    if args.json:
        print(dumps({"models": rows}, what="models"))
        return 0
    w = max(8, *(len(r["name"]) for r in rows))
    print(f"{'name':<{w}} {'kind':<20} {'n':>2} {'m':>2}  description")
    for r in rows:
        print(f"{r['name']:<{w}} {r['kind']:<20} {r['n']:>2} {r['m']:>2}  {r['description']}")
    return 0


def _vector(flag: str, values, size: int, model: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if a.size != size:
        raise UserError(f"{flag}: model '{model}' needs {size} values, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"{flag}: values must be finite, got {a.tolist()}")
    return a


def cmd_matrices(args) -> int:

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


def cmd_derive(args) -> int:

    positive("timeout", args.timeout)
    spec = load_spec(args.model)
    if args.compiler is not None and find_compiler(args.compiler) is None:
        raise UserError(
            f"--compiler {args.compiler}: no such compiler (not a file and not on PATH); leave "
            "--compiler out to use $CC, gcc or cc (or CasADi's virtual machine without one)"
        )
    out = Path(args.out) if args.out else Path(f"{spec.name}-eom")
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    if (
        out.is_dir()
        and any(out.iterdir())
        and read_derive_summary(out) is None
        and not args.force
    ):
        raise UserError(
            f"--out {out}: directory is not empty and holds no earlier derive output (use --force)"
        )
    check_writable("--out", out)
    t0 = time.perf_counter()
    model = derive(spec)
    t_derive = time.perf_counter() - t0
    t0 = time.perf_counter()
    fns = functions_of(model)  # the model derived above, not a second derivation
    t_functions = time.perf_counter() - t0
    programs, timings = {}, {"derive": t_derive, "functions": t_functions}
    if args.programs:

        t0 = time.perf_counter()
        programs = {f"{key}.program.json": json.dumps(function_data(fn), allow_nan=False)
                    for key, fn in fns.items()}
        timings["programs"] = time.perf_counter() - t0
    with warnings_as_lines():
        summary = generate(
            fns,
            out,
            compiler=args.compiler,
            timeout=args.timeout,
            timings=timings,
            cache=args.cache,
            files=programs,
            extra={"model": spec.name, "spec": spec.to_dict(), "n": spec.n, "m": spec.m},
        )
    if args.json:
        print(dumps(summary, what="summary"))
        return 0
    tm = summary["timings_s"]
    print(f"{spec.name}: wrote {summary['directory']}")
    print(
        f"  C source {summary['source']} ({summary['source_bytes'] / 1e6:.2f} MB), library "
        f"{summary['library']}, {len(summary['functions'])} CasADi files"
        + (f", {len(programs)} programs" if programs else "") + ", summary.json"
    )
    print("  timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in tm.items()))
    print(
        "  forward dynamics: "
        + ", ".join(
            f"{k} {v}"
            for k, v in summary["functions"]["forward"].items()
            if k in ("n_nodes", "n_instructions", "sx_nodes", "sx_instructions")
        )
    )
    return 0


def main(argv=None) -> int:  # pragma: no cover - convenience for ``python -m``
    from softpinn.bridge.cli import main as cli_main

    return cli_main(argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
