"""A run's report in a notebook (``notebooks/*.ipynb``): its Markdown and figures."""

from __future__ import annotations

import re
from pathlib import Path


def show_report(out_dir: str | Path) -> None:
    """Show a task run's report in a notebook: the Markdown (tables) and every figure."""
    # IPython: a notebook's, not a dependency of the package
    from IPython.display import Image, Markdown, display

    out = Path(out_dir)
    text = (out / "report.md").read_text()
    parts = re.split(r"!\[([^\]]*)\]\(([^)]+)\)", text)
    # re.split with two groups gives [text, alt, path, text, alt, path, ..., text]
    for i in range(0, len(parts), 3):
        if parts[i].strip():
            display(Markdown(parts[i]))
        if i + 2 < len(parts):
            display(Image(filename=str(out / parts[i + 2])))
