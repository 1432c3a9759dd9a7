"""One BLAS thread while the MPC solves.

The SQP's Newton step factors the Gauss-Newton Hessian with numpy (``np.linalg.cholesky``,
``solve``): an (N m) x (N m) matrix, 240 x 240 for a 3-segment arm with 12 tendons. OpenBLAS
splits that across its threads, and on a machine whose cores are busy with other work the
threads wait for each other: measured on 2 shared cores (load average 3.6-4.5, issue 46), a
solve of that arm took 565 ms with numpy's default threads and 20 ms with one, the same plan
to the last digit. :func:`one_blas_thread` holds OpenBLAS (numpy's, and scipy's where loaded) to
one thread for the duration of a block and restores what it was; where no OpenBLAS is found
(another BLAS, a system without ``/proc/self/maps``) it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator

__all__ = ["one_blas_thread"]

#: (set, get) pairs of the OpenBLAS builds numpy and scipy ship, and plain OpenBLAS
_NAMES = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
          ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
          ("openblas_set_num_threads", "openblas_get_num_threads"))

_controls: list[tuple] | None = None


def _find() -> list[tuple]:
    """(set, get) of every OpenBLAS loaded in this process."""
    found, seen = [], set()
    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower()}
    except OSError:
        return found
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                setter.argtypes, setter.restype = [ctypes.c_int], None
                getter.argtypes, getter.restype = [], ctypes.c_int
                if path not in seen:
                    seen.add(path)
                    found.append((setter, getter))
                break
    return found


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """OpenBLAS on one thread inside the block (see the module's note)."""
    global _controls
    if _controls is None:
        import numpy  # noqa: F401 - its OpenBLAS is the one the solve uses; load it first

        _controls = _find()
    before = []
    for setter, getter in _controls:
        n = getter()
        if n != 1:
            setter(1)
            before.append((setter, n))
    try:
        yield
    finally:
        for setter, n in before:
            setter(n)
