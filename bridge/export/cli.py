"""``softpinn export``: a trained run as CasADi Functions and generated C (flags onto
:func:`softpinn.bridge.export.export_run`). Wired into the CLI by ``register(subparsers)``."""

from __future__ import annotations

import json
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="a trained network as CasADi Functions and generated C (for control)",
        description=(
            "Rebuild a trained network in CasADi from its weights (eq. 6 / eq. 7 computed "
            "symbolically) and write model.casadi (the Function qdd(q, qd, u)), one "
            "<name>.casadi per Function (qdd, field, step, M, M_inv, G, D, A), model.c, "
            "model.h, model.so (compiled through the code cache) and model.json (metadata)."
        ),
    )
    p.add_argument("run", metavar="RUN", help="run directory written by `softpinn train`")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--member", type=int, default=None, metavar="K",
                       help="the ensemble member with seed K (default: the best member)")
    which.add_argument("--mean", action="store_true",
                       help="the mean of all members' vector fields")
    p.add_argument("--force", action="store_true", help="overwrite a non-empty DIR")
    p.add_argument("--json", action="store_true", help="print model.json")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    from softpinn.bridge.export.writer import export_run

    def log(text):
        if not args.json:
            print(f"export: {text}", file=sys.stderr, flush=True)

    result = export_run(args.run, args.out, member=args.member, mean=args.mean, force=args.force,
                        log=log)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        lib = result["c"]["library"] or "no library (no C compiler)"
        seeds = ", ".join(str(s) for s in result["ensemble"]["seeds"])
        averaged = result["ensemble"]["mode"] == "mean"
        if args.mean and not averaged:
            print(f"softpinn: note: {args.run} holds one model: --mean exports that one",
                  file=sys.stderr)
        print(f"exported {result['kind']} model (n={result['n']}, m={result['m']}, seed(s) "
              f"{seeds}{', mean' if averaged else ''}) to {args.out}: "
              f"{len(result['functions'])} Functions, model.c/model.h, {lib}")
    return 0
