"""Ctrl-C during a control comparison (issue 46).

CasADi checks for a pending signal inside its calls (cvodes' right-hand side, the virtual
machine) and turns Python's ``KeyboardInterrupt`` into a ``RuntimeError`` of the call: in the
closed loop that read as the plant "giving up" (a diverged loop), and the comparison went on
with the next reference. :class:`Interrupts` therefore takes SIGINT over while a comparison
runs: the first one only sets :attr:`~Interrupts.pending`, which the comparison checks between
control steps and before each build (:meth:`~Interrupts.check` raises ``KeyboardInterrupt``
there, so the CasADi call in flight finishes normally); a second one raises at once. An
exception raised while an interrupt is pending (a C compiler killed by the same Ctrl-C) is
turned into ``KeyboardInterrupt`` when the block ends. The previous handler is put back.
Outside the main thread (where Python allows no handler) or where SIGINT is ignored, nothing
changes.
"""

from __future__ import annotations

import signal
import threading

__all__ = ["Interrupts"]


class Interrupts:
    """``with Interrupts() as guard: ... guard.check() ...``: SIGINT deferred to ``check``."""

    def __init__(self):
        self.pending = False
        self._previous = None
        self._installed = False

    def _handle(self, signum, frame):
        if self.pending:  # the second Ctrl-C: at once, wherever Python is
            raise KeyboardInterrupt
        self.pending = True

    def check(self) -> None:
        """Raise ``KeyboardInterrupt`` where a Ctrl-C came since the block began."""
        if self.pending:
            raise KeyboardInterrupt

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            previous = signal.getsignal(signal.SIGINT)
            if previous not in (signal.SIG_IGN, None):
                self._previous = previous
                signal.signal(signal.SIGINT, self._handle)
                self._installed = True
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._previous)
            self._installed = False
        if self.pending and (kind is None or not issubclass(kind, KeyboardInterrupt)):
            raise KeyboardInterrupt from exc
