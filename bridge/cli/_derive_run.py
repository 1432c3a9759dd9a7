"""``softpinn derive``: the equations of motion of a model, derived once, as C source, a shared
library, CasADi files, ``summary.json`` and (``--programs``) replayable programs (its parser:
:mod:`bridge.cli.derive`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from softpinn.bridge.base import outputs
from softpinn.bridge.cli.checks import check_writable, positive, warnings_as_lines
from softpinn.bridge.exact.serialize import function_data
from softpinn.errors import UserError
from softpinn.symbolic import (
    derive,
    dumps,
    find_compiler,
    functions_of,
    generate,
    load_spec,
    read_derive_summary,
)


def run(args) -> int:
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
    outputs.hold(out, "derive")  # one writer of --out at a time (softpinn.locks)
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
