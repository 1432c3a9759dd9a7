"""``softpinn cache``: what softpinn keeps between runs (compiled C, XLA's programs), and
clearing it; run in :mod:`bridge.cli._cache_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "cache",
        help="show (or --clear) the compiled C and XLA programs softpinn keeps between runs",
        description=(
            "Show where softpinn keeps what it compiles between runs and how much: the shared "
            "libraries of derived models, simulation kernels and controllers ($SOFTPINN_CACHE, "
            "else ~/.cache/softpinn) and XLA's compiled programs ($SOFTPINN_JIT_CACHE, else jax/ "
            "in the first; one folder per machine and jaxlib build). Both are rebuilt when "
            "missing; --clear removes what softpinn wrote there and nothing else."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("--clear", action="store_true",
                   help="remove the cached libraries and programs (they are rebuilt when next "
                   "needed)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _cache_run  # deferred: jax/casadi at start-up

    return _cache_run.run(args)
