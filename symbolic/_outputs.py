"""Writing outputs so that an interrupted command leaves nothing that blocks or pollutes a rerun.

* A file or folder is built under a temporary sibling name,
  ``.<name>.partial-<pid>@<host>-<random>``, and renamed into place when it is complete
  (:func:`partial_path`, :func:`install_file`). A sibling left by a killed run (its process is
  gone) is removed by the next run that writes the same output (:func:`remove_stale_partials`);
  one of a live process is left alone. These are :mod:`softpinn.files`'s, re-exported here.
* A file being written is claimed (:func:`claimed`, :mod:`softpinn.locks`): a second writer of
  the same file, in another process, is refused with one line naming the first.
* JSON is written and printed strictly: a NaN or an infinity is refused with a message naming
  where it is (:func:`dumps`, the rule :data:`softpinn.files.REFUSE`), never written as ``NaN``
  (which is not JSON).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from softpinn import locks
from softpinn.errors import UserError
from softpinn.files import (
    FOREIGN_STALE_SECONDS,
    REFUSE,
    UNTAGGED_STALE_SECONDS,
    NonFiniteError,
    install_file,
    is_stale,
    json_text,
    owner_tag,
    partial_path,
    pid_alive,
    remove_path,
    remove_stale_partials,
    umask,
)

__all__ = [
    "FOREIGN_STALE_SECONDS",
    "UNTAGGED_STALE_SECONDS",
    "cannot_write",
    "claimed",
    "count_of",
    "dumps",
    "install_file",
    "is_stale",
    "owner_tag",
    "partial_path",
    "pid_alive",
    "remove_path",
    "remove_stale_partials",
    "umask",
]


def cannot_write(what: str, path: Path, exc: OSError) -> UserError:
    """The one-line error for an output that cannot be written."""
    why = exc.strerror or type(exc).__name__
    return UserError(f"{what} {path}: cannot write there ({why})")


def dumps(value: Any, *, what: str = "output", **kwargs) -> str:
    """Strict JSON text (:func:`softpinn.files.json_text` under the rule ``REFUSE``, nothing
    after it): a NaN or an infinity is refused with one line naming the first one; keywords as
    :func:`json.dumps` (no indent unless given)."""
    kwargs.setdefault("indent", None)
    try:
        return json_text(value, nonfinite=REFUSE, end="", **kwargs)
    except NonFiniteError as exc:
        raise UserError(
            f"{what}: {exc.where} is not a finite number; JSON cannot hold NaN or infinity"
        ) from None


def count_of(count: int, word: str, plural: str | None = None) -> str:
    """'1 segment', '2 segments', '0 trajectories' (``plural``: an irregular plural)."""
    return f"{count} {word if count == 1 else (plural or word + 's')}"


@contextlib.contextmanager
def claimed(paths: Iterable[Path], command: str) -> Iterator[None]:
    """Hold the exclusive claim (:func:`softpinn.locks.hold`) on each of ``paths`` for the
    block, ``command`` naming the writer; claims held before (the command line's, for the
    whole command) are kept after it."""
    with locks.scope():
        for path in paths:
            locks.hold(path, command, flag="out")
        yield
