"""Writing outputs so that an interrupted command leaves nothing that blocks or pollutes a rerun.

* A file or folder is built under a temporary sibling name, ``.<name>.partial-<pid>@<host>``,
  and renamed into place when it is complete (:func:`partial_path`, :func:`install_file`).
  A sibling left by a killed run (its process is gone) is removed by the next run that writes
  the same output (:func:`remove_stale_partials`); one of a live process is left alone.
* JSON is written and printed strictly: a NaN or an infinity is refused with a message naming
  where it is (:func:`dumps`), never written as ``NaN`` (which is not JSON).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softpinn.errors import UserError

_HOST = "".join(c if c.isalnum() or c in "._" else "_" for c in socket.gethostname()) or "host"

#: a temporary entry whose writer runs on another host is removed only once it is this old
FOREIGN_STALE_SECONDS = 24 * 3600.0
#: an untagged temporary entry (written by an older version) is removed once it is this old
UNTAGGED_STALE_SECONDS = 3600.0


def owner_tag() -> str:
    """``<pid>@<host>``: who writes a temporary file or folder (see :func:`is_stale`)."""
    return f"{os.getpid()}@{_HOST}"


def partial_path(target: str | os.PathLike) -> Path:
    """The temporary sibling under which ``target`` is built: ``.<name>.partial-<pid>@<host>``."""
    target = Path(target)
    return target.with_name(f".{target.name}.partial-{owner_tag()}")


def pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OSError:
        return False
    return True


def is_stale(path: Path, tag: str, *, now: float | None = None) -> bool:
    """Whether a temporary entry tagged ``<pid>@<host>`` (or untagged) was left by a writer that
    is gone: on this host its process no longer runs; on another host it is older than
    :data:`FOREIGN_STALE_SECONDS`; untagged, older than :data:`UNTAGGED_STALE_SECONDS`."""
    pid_text, at, host = tag.partition("@")
    if host == _HOST and pid_text.isdigit():
        return not pid_alive(int(pid_text))
    try:
        age = (time.time() if now is None else now) - path.lstat().st_mtime
    except FileNotFoundError:
        return False
    return age > (FOREIGN_STALE_SECONDS if at else UNTAGGED_STALE_SECONDS)


def remove_path(path: Path) -> None:
    """Remove a file, link or folder; nothing if it is already gone."""
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink()
    except FileNotFoundError:
        pass


def remove_stale_partials(target: str | os.PathLike) -> list[Path]:
    """Remove the temporary siblings of ``target`` left by killed runs; return what went."""
    target = Path(target)
    prefix = f".{target.name}.partial-"
    removed = []
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return removed
    for entry in entries:
        if entry.name.startswith(prefix) and is_stale(entry, entry.name[len(prefix) :]):
            remove_path(entry)
            removed.append(entry)
    return removed


def umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def install_file(tmp: Path, target: Path, *, mode: int = 0o666) -> None:
    """Give ``tmp`` the usual permissions and rename it onto ``target`` (atomic)."""
    os.chmod(tmp, mode & ~umask())
    os.replace(tmp, target)


def cannot_write(what: str, path: Path, exc: OSError) -> UserError:
    """The one-line error for an output that cannot be written."""
    why = exc.strerror or type(exc).__name__
    return UserError(f"{what} {path}: cannot write there ({why})")


# --------------------------------------------------------------------------------------------
# Strict JSON


def non_finite(value: Any, where: str = "") -> str | None:
    """Where the first NaN or infinity in ``value`` sits (``M_inv[0][1]``), else None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (where or "value")
    if isinstance(value, Mapping):
        for k, v in value.items():
            found = non_finite(v, f"{where}.{k}" if where else str(k))
            if found:
                return found
        return None
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            found = non_finite(v, f"{where}[{i}]")
            if found:
                return found
        return None
    return None


def dumps(value: Any, *, what: str = "output", **kwargs) -> str:
    """``json.dumps`` that refuses NaN and infinities (strict JSON) with a message naming the
    first one; anything else as :func:`json.dumps`."""
    try:
        return json.dumps(value, allow_nan=False, **kwargs)
    except ValueError:
        where = non_finite(value) or "a value"
        raise UserError(
            f"{what}: {where} is not a finite number; JSON cannot hold NaN or infinity"
        ) from None


def count_of(count: int, word: str, plural: str | None = None) -> str:
    """'1 segment', '2 segments', '0 trajectories' (``plural``: an irregular plural)."""
    return f"{count} {word if count == 1 else (plural or word + 's')}"
