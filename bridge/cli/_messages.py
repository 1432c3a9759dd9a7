"""What ``softpinn`` says when a command stops early: a library error naming the flag the user
typed, and after Ctrl-C how to go on."""

from __future__ import annotations

import argparse
import re
from pathlib import Path


def as_flag(message: str, parser: argparse.ArgumentParser, args) -> str:
    """Library errors name settings by their field (``lr: expected ...``); on the command line
    the user typed a flag, so a message that starts with a field of the running command's
    options names that flag instead (``--lr: expected ...``)."""
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


def resume_hint(args) -> str:
    """How to go on after Ctrl-C where a command can: train's checkpoint, reproduce's stages."""
    out = getattr(args, "out", None)
    if args.command == "train" and out and (Path(out) / "checkpoint.eqx").is_file():
        return (f"; {out} keeps the last finished epoch: the same command with --resume "
                "continues from there")
    if args.command == "reproduce" and out and Path(out).is_dir():
        return f"; the same command again reuses the finished stages in {out}"
    return ""
