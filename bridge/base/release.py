"""Undo the claim of an output folder (:func:`softpinn.bridge.base.outputs.claim`) on a
refusal after it (issue 44: a refused command leaves nothing): a folder that was new is
removed, one that was empty emptied again; one that held something before keeps the
unfinished claim, as after an interruption (the next run of the same command takes it over).
``softpinn control`` (:func:`softpinn.bridge.control.compare.compare`) and ``softpinn
analyze`` use it.

    state = before_claim(out)
    out = outputs.claim(out, "control")
    try:
        ...
    except UserError:
        release(out, state)
        raise
"""

from __future__ import annotations

import shutil
from pathlib import Path

__all__ = ["before_claim", "release"]


def before_claim(out) -> bool | None:
    """Whether ``out`` is new (True), an empty folder (False) or holds something (None)."""
    out = Path(out)
    if not out.exists():
        return True
    return False if out.is_dir() and not any(out.iterdir()) else None


def release(out, state: bool | None) -> None:
    """Remove what a refused command claimed in ``out`` (``state``: :func:`before_claim`)."""
    out = Path(out)
    if state is True:
        shutil.rmtree(out, ignore_errors=True)
    elif state is False and out.is_dir():
        for p in out.iterdir():
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
