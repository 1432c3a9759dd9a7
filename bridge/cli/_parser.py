"""The parser classes of the command line (argparse alone: imported at start-up).

:class:`Parser` prints errors as one line; a command's flags may be added only when that command
is parsed (:meth:`Parser.defer`), so that ``softpinn --help`` imports no library a command's
flags read their defaults from (``train``'s from :class:`softpinn.learn.TrainConfig`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``softpinn: error: ...`` and exit status 2."""

    _pending: Callable[[argparse.ArgumentParser], None] | None = None

    def error(self, message: str):  # noqa: D102 - argparse API
        print(f"softpinn: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(2)

    def defer(self, add_arguments: Callable[[argparse.ArgumentParser], None]) -> None:
        """Add the flags with ``add_arguments(self)`` when this parser first parses (its
        ``--help`` included), not now."""
        self._pending = add_arguments

    def complete(self) -> Parser:
        """Add the deferred flags now (once)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending(self)
        return self

    def parse_known_args(self, args=None, namespace=None):  # noqa: D102 - argparse API
        self.complete()
        return super().parse_known_args(args, namespace)


class DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, unless the help says it already (options
    whose default is worked out from the data or the spec) or there is none to show."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default is None or action.default is False or "default" in text:
            return text
        return super()._get_help_string(action)
