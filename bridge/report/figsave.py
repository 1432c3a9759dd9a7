"""How report figures are written: a 300 dpi PNG for the report and, beside it, a vector PDF of
the same figure for print (issue 19: figures a researcher can put in a paper)."""

from __future__ import annotations

from pathlib import Path

#: the resolution of every report PNG
DPI = 300


def save_for_print(fig, path: str | Path, *, dpi: int = DPI, pdf: bool = True) -> Path:
    """Write ``fig`` to ``path`` (PNG at ``dpi``) and, with ``pdf``, to ``path`` with the
    suffix ``.pdf``; returns the PNG's path."""
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    if pdf:
        fig.savefig(path.with_suffix(".pdf"))
    return path
