"""Why a member's training stopped: a :class:`StopReason` and the sentence that details it.

A member's ``metrics.json`` (and the checkpoint's header, per member) records both: ``"stopped"``
the sentence shown to the user ("early stop at epoch 40 (patience 10)"), unchanged, and
``"stop_reason"`` the enum's value ("patience"). Readers decide on the reason, never on the
wording: :meth:`Stop.read` takes a metrics dict, :meth:`Stop.read_all` a checkpoint's header.
Run folders written before ``"stop_reason"`` existed have the sentence alone;
:meth:`StopReason.from_detail` derives the reason from it, the one place that reads those
sentences (a documented fallback for old folders).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["Stop", "StopReason"]


class StopReason(enum.Enum):
    """Why a member of a training run stopped (or that it has not)."""

    #: still training (a checkpoint's member, or a run cut short without saying so)
    RUNNING = "running"
    #: ran its AdamW epochs to the end (and the L-BFGS iterations after them)
    COMPLETED = "completed"
    #: early stop: the test loss did not improve for ``patience`` evaluations
    PATIENCE = "patience"
    #: early stop: the test loss stayed above ``overfit`` times its best for
    #: ``overfit_evals`` evaluations
    OVERFIT = "overfit"
    #: the test loss reached ``target_loss``
    TARGET = "target"
    #: the loss became NaN or inf; the member keeps its last good parameters
    DIVERGED = "diverged"
    #: Ctrl-C (or a sweep's scheduler) ended the run; ``--resume`` continues it
    INTERRUPTED = "interrupted"
    #: a sentence of an old run folder that names none of the above
    UNKNOWN = "unknown"

    @property
    def early(self) -> bool:
        """An early stop (patience or overfit)."""
        return self in (StopReason.PATIENCE, StopReason.OVERFIT)

    @classmethod
    def from_detail(cls, detail: str) -> StopReason:
        """The reason a ``"stopped"`` sentence states: the fallback for run folders and
        checkpoints written before ``"stop_reason"`` was recorded beside it. The sentences
        parsed here are the ones :mod:`._ensemble` writes (their wording must not change)."""
        text = str(detail)
        if text == "running":
            return cls.RUNNING
        if text.startswith("completed"):
            return cls.COMPLETED
        if text.startswith("early stop"):
            return cls.OVERFIT if "(overfit" in text else cls.PATIENCE
        if text.startswith("reached"):
            return cls.TARGET
        if text.startswith("diverged"):
            return cls.DIVERGED
        if text.startswith("interrupted"):
            return cls.INTERRUPTED
        return cls.UNKNOWN

    @classmethod
    def parse(cls, value, detail: str = "") -> StopReason:
        """``value`` (a recorded ``"stop_reason"``), or where there is none the reason
        ``detail`` states (:meth:`from_detail`); a value this version does not know is
        UNKNOWN."""
        if value is None:
            return cls.from_detail(detail)
        try:
            return cls(value)
        except ValueError:
            return cls.UNKNOWN


@dataclass(frozen=True)
class Stop:
    """A reason and the sentence that details it ("early stop at epoch 40 (patience 10)")."""

    reason: StopReason
    detail: str

    @classmethod
    def read(cls, metrics: Mapping) -> Stop:
        """The stop a member's metrics record (``"stop_reason"`` and ``"stopped"``)."""
        detail = str(metrics.get("stopped", ""))
        return cls(StopReason.parse(metrics.get("stop_reason"), detail), detail)

    @classmethod
    def read_all(cls, header: Mapping) -> list[Stop]:
        """The members' stops a checkpoint's header records (``"stopped"`` and
        ``"stop_reason"``, one entry per member; a checkpoint written before ``"stop_reason"``:
        the reasons its sentences state)."""
        details = list(header["stopped"])
        reasons = header.get("stop_reason") or [None] * len(details)
        return [cls(StopReason.parse(r, d), d) for d, r in zip(details, reasons, strict=True)]
