"""Exclusive claims on outputs: one writer per output folder or file at a time (issue 44).

A command that writes a folder or a file that takes a while (``train``, ``simulate``,
``import``, ``export``, ``analyze``, ``reproduce``, ``sweep``, ``control``, ``derive``) holds
an OS lock on it for as long as it works: :func:`hold` takes ``fcntl.flock(LOCK_EX |
LOCK_NB)`` on a lock file beside the output, ``.<name>.lock`` (the output's folder is left
as it was: no file of ours inside it), and writes its owner into it (pid, host, command,
since when). A second writer, started at the same time or later, is refused with one line
naming the holder (:func:`busy`); nothing of it is written.

* The lock is the process's: it is held until :func:`release`, the end of the :func:`scope`
  that took it (the command line runs every command in one; ``learn.train`` runs in one), or
  the process's exit. Taking it again in the same process is a no-op (re-entrant).
* A holder that dies (SIGKILL included) loses its lock with its process: the OS drops a
  flock when its last descriptor closes, so a stale lock file never blocks. A lock released
  normally removes its file (and any folder made for it that is still empty); one left by a
  killed process is taken over by the next writer and removed when that one ends.
* The file is unlinked before it is closed; a writer that locked the old file checks that
  it still holds the file at that path and tries again otherwise (never two holders).
* Where no lock can be taken (a folder we may not write beside, a file system without
  flock) the command goes on unlocked, as before.

Linux and macOS (``fcntl``); a leaf: the standard library and :mod:`softpinn.errors` only.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import json
import os
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from softpinn.errors import UserError

#: ``.<name>.lock`` beside the output
SUFFIX = ".lock"
#: how long a refused writer waits for the holder's name to be written (seconds)
_OWNER_WAIT = 0.5
#: attempts before a lock seen busy is called busy (a probe holds it for microseconds)
_TRIES = 5

_HOST = socket.gethostname() or "host"


@dataclass
class _Held:
    path: Path
    fd: int
    pid: int
    thread: int
    made: list[Path] = field(default_factory=list)


_HELD: dict[str, _Held] = {}
_GUARD = threading.RLock()


def lock_path(target: str | os.PathLike) -> Path:
    """The lock file of ``target`` (a folder or a file): ``.<name>.lock`` beside it, the
    path resolved (``out``, ``./out/`` and a link to it share one lock)."""
    real = Path(os.path.realpath(os.path.expanduser(os.fspath(target))))
    if not real.name:  # the root folder
        return real / f".softpinn{SUFFIX}"
    return real.with_name(f".{real.name}{SUFFIX}")


def holds(target: str | os.PathLike) -> bool:
    """Whether this process holds ``target``'s lock."""
    held = _HELD.get(str(lock_path(target)))
    return held is not None and held.pid == os.getpid()


def hold(target: str | os.PathLike, command: str, *, flag: str = "out") -> bool:
    """Take the exclusive claim on ``target`` for ``command`` (see the module's docstring), or
    raise :class:`UserError`, one line starting ``<flag>: <target>:`` and naming the process
    that holds it. True if taken now, False if this process held it already (or no lock can
    be taken there)."""
    path = lock_path(target)
    key = str(path)
    with _GUARD:
        held = _HELD.get(key)
        if held is not None and held.pid == os.getpid():
            return False
        made = _make_folders(path.parent)
        try:
            fd = _acquire(path, command, target, flag)
        except BaseException:
            _remove_folders(made)
            raise
        if fd is None:
            _remove_folders(made)
            return False
        _HELD[key] = _Held(path, fd, os.getpid(), threading.get_ident(), made)
        return True


def release(target: str | os.PathLike) -> None:
    """Give up the claim on ``target`` (nothing if this process does not hold it): its lock
    file is removed, and the folders made for it if they are still empty."""
    _release_key(str(lock_path(target)))


def release_all() -> None:
    """Give up every claim this process holds (at exit)."""
    for key in list(_HELD):
        _release_key(key)


@contextlib.contextmanager
def scope() -> Iterator[None]:
    """The claims this thread takes inside are given up when it ends (however it ends); those
    held before it are kept. Also a decorator (``@scope()``)."""
    me = threading.get_ident()
    with _GUARD:
        before = set(_HELD)
    try:
        yield
    finally:
        for key, held in list(_HELD.items()):
            if key not in before and held.thread == me:
                _release_key(key)


def check_free(target: str | os.PathLike, *, flag: str = "out") -> None:
    """Raise the one-line :class:`UserError` of :func:`hold` where another process holds
    ``target``; takes nothing, writes nothing (a check before the work starts)."""
    path = lock_path(target)
    if holds(target):
        return
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return  # no lock file: nobody holds it
    try:
        if _busy(fd):
            raise busy(target, _owner(fd), flag)
    finally:
        os.close(fd)


def busy(target: str | os.PathLike, owner: dict, flag: str = "out") -> UserError:
    """The one line for an output another process is writing."""
    pid, host = owner.get("pid"), owner.get("host")
    who = f"softpinn {owner['command']}" if owner.get("command") else "another softpinn command"
    where = f"process {pid}@{host}" if pid and host else "another process"
    since = f", since {owner['since']}" if owner.get("since") else ""
    return UserError(f"{flag}: {target}: {who} ({where}{since}) is writing there; wait for it "
                     "to finish, or write somewhere else")


# --------------------------------------------------------------------------------------------


def _acquire(path: Path, command: str, target, flag: str) -> int | None:
    """A descriptor of ``path`` holding its flock, the owner written; None where no lock can
    be taken (the command goes on unlocked)."""
    for _ in range(20):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError:
            return None  # no write permission beside the output, read-only, ...: unlocked
        try:
            if _busy(fd, exclusive=True):
                raise busy(target, _owner(fd), flag)
        except OSError:  # a file system without flock
            os.close(fd)
            return None
        except BaseException:
            os.close(fd)
            raise
        try:  # the file locked must still be the one at ``path`` (a releaser unlinks it)
            now = os.stat(path)
            mine = os.fstat(fd)
            same = (now.st_ino, now.st_dev) == (mine.st_ino, mine.st_dev)
        except OSError:
            same = False
        if not same:
            os.close(fd)
            continue
        text = json.dumps({"pid": os.getpid(), "host": _HOST, "command": command,
                           "since": time.strftime("%Y-%m-%d %H:%M:%S")}) + "\n"
        with contextlib.suppress(OSError):  # a full disk: locked all the same, owner unnamed
            os.ftruncate(fd, 0)
            os.pwrite(fd, text.encode("utf-8"), 0)
        return fd
    return None


def _busy(fd: int, *, exclusive: bool = False) -> bool:
    """Whether another descriptor holds a flock on ``fd``'s file. ``exclusive``: keep the
    exclusive lock when it is free; else the probe's shared lock is dropped at once."""
    mode = (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB
    for attempt in range(_TRIES):
        try:
            fcntl.flock(fd, mode)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            if attempt + 1 < _TRIES:
                time.sleep(0.02)
            continue
        if not exclusive:
            fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    return True


def _owner(fd: int) -> dict:
    """Who holds the lock, as written in its file (the holder writes it just after taking it:
    wait a moment for it); {} where it cannot be read."""
    deadline = time.monotonic() + _OWNER_WAIT
    while True:
        try:
            text = os.pread(fd, 4096, 0).decode("utf-8", "replace")
            owner = json.loads(text)
            if isinstance(owner, dict) and owner.get("pid"):
                return owner
        except (OSError, ValueError):
            pass
        if time.monotonic() > deadline:
            return {}
        time.sleep(0.05)


def _make_folders(folder: Path) -> list[Path]:
    """Make ``folder`` and its missing parents; return those made (innermost first)."""
    missing = []
    for p in (folder, *folder.parents):
        if p.exists():
            break
        missing.append(p)
    with contextlib.suppress(OSError):
        folder.mkdir(parents=True, exist_ok=True)
    return [p for p in missing if p.is_dir()]


def _remove_folders(made: list[Path]) -> None:
    for p in made:  # innermost first; only while empty
        try:
            p.rmdir()
        except OSError:
            return


def _release_key(key: str) -> None:
    with _GUARD:
        held = _HELD.pop(key, None)
    if held is None or held.pid != os.getpid():
        return  # a forked child's copy of its parent's claim: the parent's to give up
    with contextlib.suppress(OSError):
        os.unlink(held.path)  # before the lock goes: a waiter that locked it tries again
    with contextlib.suppress(OSError):
        os.close(held.fd)
    _remove_folders(held.made)


atexit.register(release_all)
