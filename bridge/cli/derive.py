"""``softpinn derive MODEL --out DIR``: C source, shared library, CasADi files and
``summary.json`` (:func:`softpinn.symbolic.generate`); run in :mod:`bridge.cli._derive_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "derive",
        help="generate C code, a shared library and CasADi files for a model",
        description="Derive the equations of motion, write the C source, compile a shared "
        "library (gcc -O1), save CasADi serialized functions and summary.json (expression "
        "sizes and timings).",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
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


def run(args) -> int:
    from softpinn.bridge.cli import _derive_run  # deferred: casadi at start-up

    return _derive_run.run(args)
