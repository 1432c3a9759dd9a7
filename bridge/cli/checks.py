"""Checks and warning lines shared by the symbolic-side commands (``derive``, ``simulate``):
one-line errors before any work starts, the compiler fallback warning as one line."""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path

import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic import CompilerWarning


@contextlib.contextmanager
def warnings_as_lines():
    """Show the compiler fallback warning as one line ``softpinn: warning: ...``."""

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CompilerWarning)
        try:
            yield
        finally:
            for w in caught:
                if issubclass(w.category, CompilerWarning):
                    print(f"softpinn: warning: {w.message}", file=sys.stderr)
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def positive(field: str, value: float) -> None:
    """A finite number > 0 (NaN fails too); the message names the field, shown as its flag."""
    if not (value > 0 and np.isfinite(value)):
        what = "positive" if value == value and value < np.inf else "a finite number > 0"
        raise UserError(f"{field}: must be {what}, got {value}")


def check_writable(flag: str, path: Path) -> None:
    """Fail before the work when ``path`` cannot be created: a probe file must be creatable in
    its nearest existing ancestor (which must be a folder)."""
    import tempfile

    parent = path.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise UserError(f"{flag} {path}: cannot write there ({parent} is not a folder)")
    try:
        with tempfile.NamedTemporaryFile(prefix=".softpinn-probe-", dir=parent):
            pass
    except OSError as exc:
        raise UserError(
            f"{flag} {path}: cannot write there ({parent}: {exc.strerror or type(exc).__name__})"
        ) from None
