"""The C compiler as a child process: found (``$CC``, gcc, cc), run with a timeout, and never
outliving its command.

The compiler runs in its own process group under a small supervisor (Linux): on a timeout, an
interrupt or any other exception the whole group is killed (cc1 included) and the temporary
output removed; if this process is killed outright (SIGKILL), the kernel tells the supervisor
(``PR_SET_PDEATHSIG``) and it kills the group. The library appears atomically (a temporary file
in the same folder, then ``os.replace``).
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from softpinn.errors import UserError
from softpinn.symbolic import _outputs as outputs

#: Compiler flags: -O1 compiles 1.5-6x faster than -O2 and runs as fast (docs/pitfalls.md).
DEFAULT_FLAGS: tuple[str, ...] = ("-O1", "-fPIC", "-shared")
DEFAULT_TIMEOUT = 600.0
#: what a timeout's message advises by default: a true model's C grows with its quadrature
QUADRATURE_ADVICE = "raise the timeout or use fewer quadrature nodes"


class CompilerError(UserError):
    """The C compiler failed or ran past its timeout."""


class CompilerTimeout(CompilerError):
    """The C compiler ran past its timeout (and was killed).

    ``head``: what ran past which limit; ``timeout``: the limit in seconds. The message is the
    head and advice; :meth:`advised` gives the same error with the caller's advice (a learned
    network's export has no quadrature nodes to reduce).
    """

    def __init__(self, head: str, advice: str = QUADRATURE_ADVICE, *, timeout: float = 0.0):
        super().__init__(f"{head}; {advice}")
        self.head, self.advice, self.timeout = head, advice, timeout

    def advised(self, advice: str) -> CompilerTimeout:
        """This timeout with ``advice`` in place of its own."""
        return CompilerTimeout(self.head, advice, timeout=self.timeout)


def find_compiler(compiler: str | os.PathLike | None = None) -> str | None:
    """Absolute path of the C compiler, or None if there is none.

    ``compiler`` (a name or a path) wins; else ``$CC``; else ``gcc``, then ``cc``.
    """
    candidates = [str(compiler)] if compiler is not None else []
    if compiler is None:
        if os.environ.get("CC"):
            candidates.append(os.environ["CC"])
        candidates += ["gcc", "cc"]
    for c in candidates:
        found = shutil.which(c)
        if found:
            return str(Path(found).absolute())
    return None


def compile_c(
    source: Path,
    library: Path,
    *,
    compiler: str,
    flags: Sequence[str] = DEFAULT_FLAGS,
    timeout: float = DEFAULT_TIMEOUT,
    libraries: Sequence[str] = (),
) -> float:
    """Compile ``source`` into the shared library ``library`` atomically; return the seconds taken.

    ``libraries`` (such as ``-lmvec``) follow ``-lm`` on the command line.

    The output goes to a temporary file in the same directory, installed with ``os.replace``.
    On timeout, on an interrupt or any other exception the compiler's whole process group is
    killed and the temporary file removed; if this process is killed outright, the supervisor
    kills the group (see the module docstring).
    """
    if not (timeout > 0 and math.isfinite(timeout)):
        raise UserError(f"timeout: expected a finite number of seconds > 0, got {timeout}")
    library.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{library.stem}-", suffix=".so.tmp", dir=library.parent)
    os.close(fd)
    cmd = [compiler, *flags, str(source), "-o", tmp, "-lm", *libraries]
    start = time.perf_counter()
    try:
        proc = subprocess.Popen(
            _supervised(cmd),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,
        )
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            raise CompilerTimeout(
                f"C compiler {compiler} ran past its timeout of {timeout:g} s on {source}",
                timeout=timeout,
            ) from None
        except BaseException:  # KeyboardInterrupt, SystemExit, ...: the compiler goes too
            _kill_group(proc)
            raise
        if proc.returncode != 0:
            lines = err.decode(errors="replace").strip().splitlines()
            own = [ln[len(_SUPERVISOR_TAG):].strip() for ln in lines
                   if ln.startswith(_SUPERVISOR_TAG)]
            last = [f"cannot run it ({own[-1]})"] if own else lines[-1:]
            raise CompilerError(
                f"C compiler {compiler} failed on {source} (exit {proc.returncode}): "
                f"{(last or ['(no output)'])[0]}"
            )
        os.chmod(tmp, 0o777 & ~outputs.umask())
        os.replace(tmp, library)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return time.perf_counter() - start


_SUPERVISOR_TAG = "softpinn-supervisor:"

#: Runs the compiler as its child, in the process group the caller made for it. When the caller
#: dies (even by SIGKILL) the kernel sends this supervisor SIGTERM (PR_SET_PDEATHSIG), and it kills
#: the whole group, compiler and cc1 included; SIGTERM from anyone else does the same.
_SUPERVISOR = r"""
import os, signal, subprocess, sys
def stop(*_):
    os.killpg(0, signal.SIGKILL)
signal.signal(signal.SIGTERM, stop)
signal.signal(signal.SIGHUP, stop)
try:
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
except Exception:
    pass
if os.getppid() != int(sys.argv[1]):
    stop()
try:
    sys.exit(subprocess.call(sys.argv[2:]))
except OSError as e:
    print("softpinn-supervisor: " + str(e), file=sys.stderr)
    sys.exit(127)
"""


def _supervised(cmd: list[str]) -> list[str]:
    """``cmd`` under the supervisor (Linux, where ``prctl`` exists), else unchanged."""
    if not sys.platform.startswith("linux") or not sys.executable:
        return cmd
    return [sys.executable, "-I", "-S", "-c", _SUPERVISOR, str(os.getpid()), *cmd]


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill the compiler's whole process group (its children, such as cc1, too) and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:  # pragma: no cover - a child that escaped the group
        proc.kill()
        proc.wait()
