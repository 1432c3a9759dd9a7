"""``softpinn models``: the presets (name, kind, n, m, description); run in
:mod:`bridge.cli._models_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "models",
        help="list the model presets",
        description="List the model presets (name, kind, n, m, description).",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args) -> int:
    from softpinn.bridge.cli import _models_run  # deferred: casadi at start-up

    return _models_run.run(args)
