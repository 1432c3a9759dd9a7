"""``softpinn export RUN --out DIR``: a trained network as CasADi Functions and generated C (for
control); run in :mod:`bridge.cli._export_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "export",
        help="a trained network as CasADi Functions and generated C (for control)",
        description=(
            "Rebuild a trained network in CasADi from its weights (eq. 6 / eq. 7 computed "
            "symbolically) and write model.casadi (the Function qdd(q, qd, u)), one "
            "<name>.casadi per Function (qdd, field, step, M, M_inv, G, D, A), model.c, "
            "model.h, model.so (compiled through the code cache) and model.json (metadata). "
            "The C is compiled before DIR is written: a compile past --compile-timeout leaves "
            "DIR as it was."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("run", metavar="RUN", help="run directory written by `softpinn train`")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--member", type=int, default=None, metavar="K",
                       help="the ensemble member with seed K (default: the best member)")
    which.add_argument("--mean", action="store_true",
                       help="the mean of all members' vector fields")
    p.add_argument("--force", action="store_true", help="overwrite a non-empty DIR")
    p.add_argument("--no-compile", dest="no_compile", action="store_true",
                   help="write the Functions, model.c and model.h but no model.so (they run in "
                        "CasADi's virtual machine; compile model.c yourself later)")
    p.add_argument("--compile-timeout", dest="compile_timeout", type=float, default=600.0,
                   metavar="S", help="seconds the C compiler may take (default 600; a large "
                                     "network's C can take several minutes on a loaded machine)")
    p.add_argument("--json", action="store_true", help="print model.json")


def run(args) -> int:
    from softpinn.bridge.cli import _export_run  # deferred: jax/casadi at start-up

    return _export_run.run(args)
