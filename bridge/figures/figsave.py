"""How report figures are written: a 300 dpi PNG for the report and, beside it, a vector PDF of
the same figure for print (issue 19: figures a researcher can put in a paper).

Quick runs (``reproduce --quick``, the notebooks' default, the tests) draw drafts instead,
inside :func:`draft_figures`: PNGs at screen resolution (:data:`DRAFT_DPI`) and no PDF. They
are the same figures; the print copies cost half of a quick run's report time (a 300 dpi PNG
and a PDF are two full draws).
"""

from __future__ import annotations

import contextvars
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: the resolution of every report PNG
DPI = 300
#: the resolution of a draft (quick run) PNG
DRAFT_DPI = 100
#: the most pixels of a report PNG: a figure too large for :data:`DPI` (task 5's 36 panels of
#: P(q), 16.6 x 13.9 in) is written at the resolution that fills it (186 dpi there, about
#: 500 px a panel; a like figure took 7.3 s to write at 300 dpi, 3.8 s at 150); figures of a
#: page's size keep 300 dpi
MAX_PIXELS = 8_000_000

_DRAFT = contextvars.ContextVar("softpinn_draft_figures", default=False)


@contextmanager
def draft_figures(draft: bool = True) -> Iterator[None]:
    """Within the block, :func:`save_for_print` and :func:`figure_dpi` write drafts (see the
    module); ``draft_figures(False)`` is a no-op block."""
    token = _DRAFT.set(bool(draft) or _DRAFT.get())
    try:
        yield
    finally:
        _DRAFT.reset(token)


def is_draft() -> bool:
    """True inside :func:`draft_figures`."""
    return _DRAFT.get()


def figure_dpi(dpi: int | None = None, fig=None) -> int:
    """The resolution to save at: ``dpi`` (default :data:`DPI`), at most :data:`DRAFT_DPI`
    in a draft, and for a figure ``fig`` at most what keeps it within :data:`MAX_PIXELS`."""
    dpi = DPI if dpi is None else int(dpi)
    if fig is not None:
        width, height = fig.get_size_inches()
        dpi = min(dpi, max(DRAFT_DPI, int((MAX_PIXELS / (width * height)) ** 0.5)))
    return min(dpi, DRAFT_DPI) if _DRAFT.get() else dpi


def save_for_print(fig, path: str | Path, *, dpi: int | None = None, pdf: bool = True) -> Path:
    """Write ``fig`` to ``path`` (PNG at ``dpi``, default :data:`DPI`) and, with ``pdf``, to
    ``path`` with the suffix ``.pdf`` (neither in a draft: see the module); returns the PNG's
    path."""
    path = Path(path)
    fig.savefig(path, dpi=figure_dpi(dpi, fig))
    if pdf and not _DRAFT.get():
        fig.savefig(path.with_suffix(".pdf"))
    return path
