"""The ``softpinn`` command line.

The CLI only maps flags onto library functions. Each group of subcommands lives in its own
module with a ``register(subparsers)`` function that adds its parsers and sets ``func`` on each;
``func(args)`` returns an exit status (or None for 0). Errors a user can fix are printed as one
line ``softpinn: error: ...`` with exit status 2 and no traceback (see ``*/errors.py``).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from softpinn.learn.jitcache import enable_compile_cache

#: Modules that contribute subcommands, in the order they appear in ``--help``.
COMMAND_MODULES = (
    "softpinn.bridge.cli.symbolic",
    "softpinn.bridge.cli.data",
    "softpinn.bridge.cli.excitation",
    "softpinn.bridge.cli.learn",
    "softpinn.bridge.cli.predict",
    "softpinn.bridge.cli.bridge",
    "softpinn.bridge.cli.show",
    "softpinn.bridge.cli.sweep",
    "softpinn.bridge.export.cli",
    "softpinn.bridge.cli.control",
    "softpinn.bridge.cli.cache",
)

#: Commands that compile JAX programs: they (and the processes they start) share XLA's compiled
#: programs through the persistent cache of :mod:`softpinn.learn.jitcache`.
JIT_COMMANDS = frozenset({"train", "predict", "analyze", "reproduce", "sweep", "export", "control"})


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``softpinn: error: ...`` and exit status 2."""

    def error(self, message: str):  # noqa: D102 - argparse API
        print(f"softpinn: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(2)


class DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, unless the help says it already (options
    whose default is worked out from the data or the spec) or there is none to show."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default is None or action.default is False or "default" in text:
            return text
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
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
        importlib.import_module(name).register(sub)
    for command in sub.choices.values():  # every --help shows every default
        command.formatter_class = DefaultsFormatter
    return parser


def is_user_error(exc: BaseException) -> bool:
    return bool(getattr(type(exc), "softpinn_user_error", False))


def _as_flag(message: str, parser: argparse.ArgumentParser, args) -> str:
    """Library errors name settings by their field (``lr: expected ...``); on the command line
    the user typed a flag, so a message that starts with a field of the running command's
    options names that flag instead (``--lr: expected ...``)."""
    import re

    field, sep, rest = message.partition(": ")
    if not sep or not field.isidentifier():
        return message
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    command = sub.choices.get(getattr(args, "command", None))
    if command is None:
        return message
    flags = {a.dest: a.option_strings[0] for a in command._actions if a.option_strings}
    if field not in flags:
        return message
    # other fields the message names, where they are unmistakable (snake_case words)
    rest = re.sub(r"\b[a-z]+(?:_[a-z]+)+\b", lambda m: flags.get(m.group(0), m.group(0)), rest)
    return f"{flags[field]}: {rest}"


def _resume_hint(args) -> str:
    """How to go on after Ctrl-C where a command can: train's checkpoint, reproduce's stages."""
    from pathlib import Path

    out = getattr(args, "out", None)
    if args.command == "train" and out and (Path(out) / "checkpoint.eqx").is_file():
        return (f"; {out} keeps the last finished epoch: the same command with --resume "
                "continues from there")
    if args.command == "reproduce" and out and Path(out).is_dir():
        return f"; the same command again reuses the finished stages in {out}"
    return ""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in JIT_COMMANDS:

        enable_compile_cache()
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        print(f"softpinn: interrupted{_resume_hint(args)}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `softpinn ... | head`: the reader has gone; nothing to say
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 1
    except Exception as exc:
        if is_user_error(exc):
            message = _as_flag(" ".join(str(exc).split()), parser, args)
            print(f"softpinn: error: {message}", file=sys.stderr)
            return 2
        raise
    return 0 if status is None else int(status)


if __name__ == "__main__":
    sys.exit(main())
