"""The ``softpinn`` command line.

The CLI only maps flags onto library functions. Each command is a module of its own
(:data:`COMMAND_MODULES`) holding its parser: ``add_parser(subparsers)`` adds the command with
its help and sets ``func`` to the module's ``run``, ``add_arguments(parser)`` adds its flags, and
``run(args)`` imports the command's implementation (``_<command>_run.py``, which imports the
libraries) and returns an exit status (or None for 0). ``softpinn --help`` thus imports no
library, and ``softpinn CMD`` only what CMD needs. Errors a user can fix
(:class:`softpinn.errors.UserError`) are printed as one line ``softpinn: error: ...`` with exit
status 2 and no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from softpinn import locks
from softpinn.bridge.cli._messages import as_flag, resume_hint
from softpinn.bridge.cli._parser import DefaultsFormatter, Parser
from softpinn.errors import UserError

#: Modules that contribute subcommands, in the order they appear in ``--help``.
COMMAND_MODULES = tuple(f"softpinn.bridge.cli.{name}" for name in (
    "models", "matrices", "derive", "simulate", "import_", "init", "excitation", "train",
    "predict", "analyze", "reproduce", "show", "sweep", "export", "control", "cache"))

#: Commands that compile JAX programs: they (and the processes they start) share XLA's compiled
#: programs through the persistent cache of :mod:`softpinn.learn.jitcache`.
JIT_COMMANDS = frozenset({"train", "predict", "analyze", "reproduce", "sweep", "export", "control"})


def build_parser(*, lazy: bool = False) -> argparse.ArgumentParser:
    """The parser of every command; ``lazy``: a command's flags are added when it is parsed
    (:meth:`Parser.defer`), as :func:`main` does."""
    parser = Parser(
        prog="softpinn",
        description=(
            "Learn dynamic models of soft manipulators with physics-inspired neural networks "
            "and check them against exact PCC equations of motion."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        module = importlib.import_module(name)
        command = module.add_parser(sub)
        command.formatter_class = DefaultsFormatter  # every --help shows every default
        if lazy:
            command.defer(module.add_arguments)
        else:
            module.add_arguments(command)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(lazy=True)
    args = parser.parse_args(argv)
    if args.command in JIT_COMMANDS:
        # deferred: jax at start-up (the cache is jax's)
        from softpinn.learn.jitcache import enable_compile_cache

        enable_compile_cache()
    try:
        with locks.scope():  # the claims on outputs (softpinn.locks) end with the command
            status = args.func(args)
    except KeyboardInterrupt:
        print(f"softpinn: interrupted{resume_hint(args)}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `softpinn ... | head`: the reader has gone; nothing to say
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 1
    except UserError as exc:
        print(f"softpinn: error: {as_flag(' '.join(str(exc).split()), parser, args)}",
              file=sys.stderr)
        return 2
    return 0 if status is None else int(status)


if __name__ == "__main__":
    sys.exit(main())
