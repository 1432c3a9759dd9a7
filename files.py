"""Files written whole, strict JSON, and the arrays of a dataset file: the one implementation
that symbolic, learn and bridge share. A leaf: it imports the standard library and numpy only
(errors are ``OSError`` and :class:`NonFiniteError`; each caller words its own one-line
``UserError``).

Writing a file whole: :func:`atomic_write`
    The bytes go to a temporary sibling ``.<name>.partial-<pid>@<host>-<random>``, created
    exclusively (two processes, or two threads of one, that write the same file at once never
    share a temporary file), flushed and fsync'ed, then renamed onto the name with
    :func:`os.replace` (atomic). On any error, Ctrl-C included, the sibling is removed and the
    file keeps its previous content. The file gets the usual permissions (0666 less the umask).
    A folder, or files installed together, are built under :func:`partial_path` the same way;
    a sibling left by a killed process is told by its tag (:func:`is_stale`) and removed by the
    next writer of the same name (:func:`remove_stale_partials`).

Strict JSON: :func:`json_text`, :func:`write_json`, :func:`jsonable`
    numpy arrays and scalars, tuples, paths and enums become JSON's lists, numbers and strings.
    JSON has no NaN or Infinity, and the rule for a non-finite float is named by the caller:

    * :data:`NULL` (the default, every file of results, settings, metrics, manifests and study
      records): written as ``null``, so a file always parses and a reader sees "no number"
      (issue 15: no JSON file softpinn writes holds NaN or Infinity);
    * :data:`REFUSE` (what must be finite: a dataset's meta, what the command line prints):
      :class:`NonFiniteError` naming where the first one sits (``M_inv[1][0]``), which the
      caller turns into one line for the user instead of a file or an output with holes;
    * :data:`KEEP`, the one exception, NOT strict JSON: Python's ``NaN`` / ``Infinity``, for
      the stage records and results of ``softpinn reproduce`` tasks
      (:mod:`bridge.tasks.stages`), which have always held them: a rollout that diverged has
      error ``inf`` (the paper's Table III prints ``inf``), and a stage reused from its
      ``done.json`` must give back ``inf``, not ``None`` (it would print ``—``). To go when
      the stages' results are typed.

The dataset file (``docs/dataset.md``): :data:`DATASET_ARRAYS`, :data:`DATASET_REQUIRED`,
:data:`DATASET_OPTIONAL`, :data:`DATASET_EQUILIBRIUM`, read the same by both sides
(``symbolic.simulation._datafile`` and ``learn._data``).
"""

from __future__ import annotations

import contextlib
import enum
import json
import math
import os
import secrets
import shutil
import socket
import time
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import numpy as np

# --------------------------------------------------------------------------------------------
# The dataset file

#: Every array of a dataset file but ``meta``, in the order ``softpinn simulate`` writes them:
#: ``t`` (T,), ``q``, ``qd``, ``qdd``, ``p`` (T, n), ``u`` (T, m), ``traj`` (T,).
DATASET_ARRAYS = ("t", "q", "qd", "qdd", "p", "u", "traj")
#: Arrays a file may leave out: the momenta p = M(q) q̇ (simulated data hold them; a recording
#: has none, and a Hamiltonian network then trains on the velocities, ``docs/velocity.md``).
DATASET_OPTIONAL = ("p",)
#: What every dataset file must hold: the arrays but the optional ones, and ``meta``, a 0-d
#: string of JSON.
DATASET_REQUIRED = (*(k for k in DATASET_ARRAYS if k not in DATASET_OPTIONAL), "meta")
#: Optional, all three or none: static equilibria G(q*) = A(q*) u* and their force
#: f* = G(q*) (``docs/dataset.md``), labels of the model, not samples.
DATASET_EQUILIBRIUM = ("eq_q", "eq_u", "eq_force")

# --------------------------------------------------------------------------------------------
# Temporary siblings

_HOST = "".join(c if c.isalnum() or c in "._" else "_" for c in socket.gethostname()) or "host"

#: a temporary entry whose writer runs on another host is removed only once it is this old
FOREIGN_STALE_SECONDS = 24 * 3600.0
#: an untagged temporary entry (written by an older version) is removed once it is this old
UNTAGGED_STALE_SECONDS = 3600.0


def owner_tag() -> str:
    """``<pid>@<host>``: who writes a temporary file or folder (see :func:`is_stale`); the host
    holds no ``-``, which separates the tag from a random suffix."""
    return f"{os.getpid()}@{_HOST}"


def partial_path(target: str | os.PathLike) -> Path:
    """A new temporary sibling of ``target``: ``.<name>.partial-<pid>@<host>-<random>``, a
    different name on every call (concurrent writers never share one)."""
    target = Path(target)
    return target.with_name(f".{target.name}.partial-{owner_tag()}-{secrets.token_hex(4)}")


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
    """Whether a temporary entry tagged ``<pid>@<host>`` (a ``-<random>`` suffix aside; or
    untagged) was left by a writer that is gone: on this host its process no longer runs; on
    another host it is older than :data:`FOREIGN_STALE_SECONDS`; untagged, older than
    :data:`UNTAGGED_STALE_SECONDS`."""
    pid_text, at, host = tag.partition("@")
    host = host.partition("-")[0]
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
        if entry.name.startswith(prefix) and is_stale(entry, entry.name[len(prefix):]):
            remove_path(entry)
            removed.append(entry)
    return removed


def umask() -> int:
    """The process's file-creation mask (read by setting it and setting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def install_file(tmp: Path, target: Path, *, mode: int = 0o666) -> None:
    """Give ``tmp`` the usual permissions (``mode`` less the umask) and rename it onto
    ``target`` (atomic)."""
    os.chmod(tmp, mode & ~umask())
    os.replace(tmp, target)


# --------------------------------------------------------------------------------------------
# Writing a file whole


def atomic_write(path: str | os.PathLike, data: bytes | str, *, mode: int = 0o666) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` whole (see the module's docstring); make its
    folder if need be. Raises ``OSError`` (the file keeps its previous content)."""
    path = Path(path)
    if isinstance(data, str):
        data = data.encode("utf-8")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_path(path)
    # O_EXCL: never write into another writer's file; the umask applies to ``mode``
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), mode)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


# --------------------------------------------------------------------------------------------
# Strict JSON

#: non-finite floats are written as ``null`` (files; the default)
NULL = "null"
#: non-finite floats raise :class:`NonFiniteError` (values that must be finite; printing)
REFUSE = "refuse"
#: non-finite floats as Python's ``NaN`` / ``Infinity`` (not JSON; task stage records only)
KEEP = "keep"
NONFINITE = (NULL, REFUSE, KEEP)


class NonFiniteError(ValueError):
    """A NaN or an infinity where :data:`REFUSE` allows none; ``where`` names the first one
    (``M_inv[1][0]``, ``simulation.rtol``, ``value`` for a bare number)."""

    def __init__(self, where: str):
        super().__init__(f"{where} is not a finite number; JSON cannot hold NaN or infinity")
        self.where = where


def jsonable(x: Any, *, nonfinite: str = NULL, str_keys: bool = False) -> Any:
    """``x`` as JSON's values (dict, list, str, int, float, bool, None): mappings to dicts
    (keys as they are, numpy ones as Python's; ``str_keys``: every key through ``str``), numpy
    arrays, lists and tuples to lists, numpy scalars to Python's, paths to strings, enums to
    the string of their value, and a non-finite float by the rule ``nonfinite`` (module
    docstring). Anything else is left as it is (``json`` refuses it: ``TypeError``)."""
    if nonfinite not in NONFINITE:
        raise ValueError(f"nonfinite: expected one of {NONFINITE}, got {nonfinite!r}")
    try:
        return _jsonable(x, nonfinite, str_keys)
    except _Found as found:
        raise NonFiniteError("".join(reversed(found.parts)).lstrip(".") or "value") from None


class _Found(Exception):
    """A non-finite float under :data:`REFUSE`; ``parts`` name where, innermost first (added
    on the way out, so that a value without one costs no names)."""

    def __init__(self):
        super().__init__()
        self.parts: list[str] = []


def _jsonable(x: Any, rule: str, str_keys: bool) -> Any:
    if isinstance(x, Mapping):
        out = {}
        for k, v in x.items():
            try:
                out[_key(k, str_keys)] = _jsonable(v, rule, str_keys)
            except _Found as found:
                found.parts.append(f".{k}")
                raise
        return out
    if isinstance(x, np.ndarray):
        x = x.tolist()
    if isinstance(x, list | tuple):
        out = []
        for i, v in enumerate(x):
            try:
                out.append(_jsonable(v, rule, str_keys))
            except _Found as found:
                found.parts.append(f"[{i}]")
                raise
        return out
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        if math.isfinite(x) or rule == KEEP:
            return x
        if rule == NULL:
            return None
        raise _Found
    if isinstance(x, enum.Enum):
        return str(x.value)
    if isinstance(x, PurePath):
        return str(x)
    return x


def _key(k: Any, str_keys: bool) -> Any:
    if isinstance(k, np.generic):
        k = k.item()
    return str(k) if str_keys else k


def json_text(obj: Any, *, nonfinite: str = NULL, indent: int | None = 2, end: str = "\n",
              **kwargs) -> str:
    """``obj`` as JSON text (:func:`jsonable` with the rule ``nonfinite``), ``end`` after it;
    ``indent`` and any further keyword as :func:`json.dumps`."""
    plain = jsonable(obj, nonfinite=nonfinite)
    return json.dumps(plain, indent=indent, allow_nan=nonfinite == KEEP, **kwargs) + end


def write_json(path: str | os.PathLike, obj: Any, *, nonfinite: str = NULL,
               indent: int | None = 2, end: str = "\n", **kwargs) -> Path:
    """:func:`json_text` written whole (:func:`atomic_write`); returns the path."""
    text = json_text(obj, nonfinite=nonfinite, indent=indent, end=end, **kwargs)
    return atomic_write(path, text)
