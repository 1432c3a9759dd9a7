"""Tables shaped like the paper's: matrices at chosen q (Tables I, II, V-IX), fit summaries and
the paper's Table III beside our figures, written as Markdown, CSV or LaTeX (booktabs).

A :class:`Table` is a value: column spans (group, matrix, number of columns) and rows of cells
(numbers or text). Matrix tables put one configuration q in n consecutive rows, as the paper
does: row r of a block holds q_r and row r of every matrix. Numbers are formatted at write time
(:func:`format_number`): fixed point for 1e-2 <= |x| < 1e4, scientific otherwise, ``precision``
digits after the point, like the paper's ``1.728e-03`` and ``1.293``. CSV keeps full precision
(17 significant digits) and reads back with :func:`read_csv`.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.bridge.analysis.transform_result import Status, match_word
from softpinn.bridge.analysis.transforms import as_stack
from softpinn.errors import UserError

Cell = float | int | str | None

#: Column groups of a transform table and how the paper heads them.
GROUP_TITLES = {
    "true": "mathematical model",
    "learned": "physics-based learning model",
    "transformed": "transformed learned model",
    "P": "transform",
}
_LATEX_MATRIX = {"M": "M", "M_inv": "M^{-1}", "D": "D", "G": "G", "A": "A", "P": "P"}


@dataclass(frozen=True)
class Span:
    """``ncols`` adjacent columns holding matrix ``label`` of column group ``group``."""

    group: str
    label: str
    ncols: int = 1
    latex: str | None = None  # header in LaTeX (math allowed); ``label`` escaped if None


@dataclass(frozen=True)
class Table:
    """A table: column spans, rows of cells, rows per q-block (for separators), caption."""

    spans: tuple[Span, ...]
    rows: tuple[tuple[Cell, ...], ...]
    block_rows: int = 0  # > 0: a rule after every block of this many rows
    caption: str = ""

    def __post_init__(self):
        width = sum(s.ncols for s in self.spans)
        for i, row in enumerate(self.rows):
            if len(row) != width:
                raise ValueError(f"row {i} has {len(row)} cells, the header {width}")

    @property
    def columns(self) -> tuple[str, ...]:
        """Unique flat column names: ``group label[j]`` (``group label`` for one column)."""
        out = []
        for s in self.spans:
            base = f"{s.group} {s.label}".strip()
            out += [base] if s.ncols == 1 else [f"{base}[{j + 1}]" for j in range(s.ncols)]
        return tuple(out)


# --------------------------------------------------------------------------------------------
# Number formatting


def format_number(x: Cell, precision: int = 3) -> str:
    """Paper style: ``1.293``, ``1.728e-03``, ``600.323``; text passes through."""
    if x is None:
        return ""
    if isinstance(x, str):
        return x
    if isinstance(x, bool | np.bool_):
        return str(bool(x))
    if isinstance(x, int | np.integer):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0.0:
        return f"{0.0:.{precision}f}"
    if 1e-2 <= abs(x) < 1e4 and round(abs(x), precision) != 0:
        return f"{x:.{precision}f}"
    return f"{x:.{precision}e}"


def percent_text(fraction) -> str:
    """A relative error as a percentage a reader takes in at once: '21 %', '0.35 %', '100 %',
    '1,400 %'; below 1e-6 % (exact to rounding) '0 %'; '–' where there is none."""
    if fraction is None or not np.isfinite(fraction):
        return "–"
    v = 100.0 * abs(float(fraction))
    if v < 1e-6:
        return "0 %"
    if v >= 100:
        return f"{v:,.0f} %"
    if v < 0.01:
        return f"{v:.1e} %"
    return f"{v:.2g} %"


def format_mean_std(
    mean: float | None,
    std: float | None,
    *,
    precision: int = 3,
    std_precision: int | None = None,
    horizon_s: float | None = None,
) -> str:
    """Table III style: ``5.969e-08 ± 1.69e-07``, ``0.171 ± 0.272``.

    The std follows the mean's notation: scientific with ``precision - 1`` digits after the
    point when the mean is scientific, fixed with ``precision`` digits otherwise (or
    ``std_precision`` for both). A std of ``None`` prints ``inf``, as the paper does; with
    ``horizon_s`` the horizon follows in parentheses: ``0.171 ± 0.272 (5s)``.
    """
    if mean is None:
        return "—"
    m = format_number(mean, precision)
    if std is None:
        s = "inf"
    elif "e" in m:
        sp = precision - 1 if std_precision is None else std_precision
        s = f"{float(std):.{max(sp, 0)}e}"
    else:
        sp = precision if std_precision is None else std_precision
        s = f"{float(std):.{max(sp, 0)}f}"
    text = f"{m} ± {s}"
    if horizon_s is not None:
        text += f" ({horizon_s:g}s)"
    return text


# --------------------------------------------------------------------------------------------
# Builders


def _as_columns(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    return a[:, :, None] if a.ndim == 2 else a


def matrix_table(
    q: np.ndarray,
    matrices: Sequence[tuple[str, str, np.ndarray]],
    *,
    caption: str = "",
    latex: Mapping[tuple[str, str], str] | None = None,
    per_q: Sequence[tuple[str, str, np.ndarray]] = (),
) -> Table:
    """Rows per q like Tables I, II: ``matrices`` is a list of (group, label, stack), each
    stack (N, n, c) or (N, n); q (N, n). Block i holds q_i down its first column.
    ``per_q``: (group, label, values (N,)) columns with one number per q, printed in the
    first row of each block (Table VI's alpha)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2:
        raise UserError(f"q: expected shape (N, n), got {q.shape}")
    N, n = q.shape
    stacks = []
    for group, label, a in matrices:
        a = _as_columns(a)
        if a.shape[:2] != (N, n):
            raise UserError(f"{group} {label}: expected shape ({N}, {n}, c), got {a.shape}")
        stacks.append((group, label, a))
    latex = latex or {}
    spans = [Span("", "q", 1, "$q$")]
    spans += [Span(g, lab, a.shape[2], latex.get((g, lab))) for g, lab, a in stacks]
    scalars = []
    for group, label, v in per_q:
        v = np.asarray(v, dtype=np.float64)
        if v.shape != (N,):
            raise UserError(f"{group} {label}: expected shape ({N},), got {v.shape}")
        scalars.append(v)
        spans.append(Span(group, label, 1, latex.get((group, label))))
    rows = []
    for i in range(N):
        for r in range(n):
            row: list[Cell] = [float(q[i, r])]
            for _, _, a in stacks:
                row += [float(v) for v in a[i, r]]
            row += [float(v[i]) if r == 0 else None for v in scalars]
            rows.append(tuple(row))
    return Table(tuple(spans), tuple(rows), block_rows=n, caption=caption)


def transform_table(
    q: np.ndarray,
    true,
    learned,
    result=None,
    *,
    matrices: Sequence[str] = ("M", "D", "G", "A"),
    caption: str = "",
) -> Table:
    """Table I / II: true and learned matrices at each q, then (with a transform ``result``)
    the transformed learned matrices ``P X^`` and P itself. ``true`` and ``learned`` are
    :class:`bridge.transforms.MatrixStack` or dicts; ``M_inv`` is allowed in ``matrices``."""

    true, learned = as_stack(true, "true"), as_stack(learned, "learned")
    cols, tex = [], {}
    for group, side in (("true", true), ("learned", learned)):
        for k in matrices:
            if not side.has(k) or side.block(k).shape[2] == 0:
                continue
            cols.append((group, k, side.block(k)))
            body = _LATEX_MATRIX.get(k, k)
            tex[(group, k)] = f"${body}(q)$" if group == "true" else f"$\\hat{{{body}}}(q)$"
    if result is not None:
        for k in matrices:
            if k == "M_inv" or not (true.has(k) and learned.has(k)) or true.block(k).size == 0:
                continue
            cols.append(("transformed", k, result.P @ learned.block(k)))
            body = _LATEX_MATRIX.get(k, k)
            tex[("transformed", k)] = f"$P\\hat{{{body}}}$"
        cols.append(("P", result.name, result.P))
        tex[("P", result.name)] = f"$P$ ({_latex_escape(result.name)})"
    per_q = []
    if result is not None and "alpha_per_q" in result.params:  # Table VI: alpha at each q
        per_q.append(("alpha", "at q", result.params["alpha_per_q"]))
        tex[("alpha", "at q")] = "$\\alpha(q)$"
    return matrix_table(q, cols, caption=caption, latex=tex, per_q=per_q)


def summary_table(results: Mapping[str, Any], *, caption: str = "") -> Table:
    """One row per transform: whether the fit itself went well (``ok``, or why not), what its
    total residual means (:func:`bridge.analysis.transform_result.match_word`), the relative
    residual of each matrix over all q and their root mean square, in percent, the nearest
    multiple of I (scale c, alpha = 1/c, relative distance) and, for ``smooth``, the held-out
    residual (percent)."""

    order = ("M_inv", "M", "D", "A", "G")
    blocks: list[str] = []
    for r in results.values():
        blocks += [k for k in r.residual if k not in blocks]
    blocks.sort(key=lambda k: order.index(k) if k in order else len(order))
    spans = [Span("", "transform"), Span("", "fit"), Span("", "match")]
    spans += [Span("residual", f"{k} (%)", 1, f"${_LATEX_MATRIX.get(k, k)}$ (\\%)") for k in blocks]
    spans += [
        Span("residual", "total (%)", 1, "total (\\%)"),
        Span("P ~ cI", "c"),
        Span("P ~ cI", "alpha", 1, "$\\alpha = 1/c$"),
        Span("P ~ cI", "distance"),
        Span("held-out", "residual (%)", 1, "residual (max, \\%)"),
    ]

    def pct(x):
        return None if x is None else 100.0 * float(x)

    rows = []
    for name, r in results.items():
        held = r.params.get("residual_heldout") if hasattr(r, "params") else None
        held_v = max(held.values()) if held else None
        fit = "ok" if r.status == Status.SUCCESS else str(r.status)
        rows.append(
            (name, fit, match_word(r.residual_total))
            + tuple(pct(r.residual.get(k)) for k in blocks)
            + (pct(r.residual_total), r.scale_all, r.alpha, r.distance_all, pct(held_v))
        )
    return Table(tuple(spans), tuple(rows), caption=caption)


# --------------------------------------------------------------------------------------------
# Writers


def to_markdown(table: Table, *, precision: int = 3) -> str:
    """GitHub Markdown. A table of q-blocks (a matrix's rows at each q, Tables I, II) gets one
    row per q, the block's rows stacked in each cell with ``<br>``, so that a q never spreads
    over several rows of the table."""

    def cell(x):
        return format_number(x, precision).replace("|", "\\|")

    head = "| " + " | ".join(c.replace("|", "\\|") for c in table.columns) + " |"
    rule = "|" + "|".join("---" for _ in table.columns) + "|"
    lines = [f"**{table.caption}**", ""] if table.caption else []
    lines += [head, rule]
    k = table.block_rows or 1
    for i in range(0, len(table.rows), k):
        block = table.rows[i:i + k]
        cells = ["<br>".join(cell(row[j]) for row in block) for j in range(len(block[0]))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: each character LaTeX treats specially, and what stands for it (one ``str.translate``)
_LATEX = str.maketrans({**{ch: "\\" + ch for ch in "&%$#_{}"}, "~": "\\textasciitilde{}",
                        "^": "\\textasciicircum{}", "\\": "\\textbackslash{}",
                        "±": "$\\pm$", "—": "--"})


def _latex_escape(text: str) -> str:
    return text.translate(_LATEX)


def to_latex(
    table: Table, *, precision: int = 3, label: str | None = None, resize_above: int = 12
) -> str:
    """A booktabs ``table`` environment: group headers with ``\\cmidrule``, matrix headers
    spanning their columns, ``\\midrule`` between q-blocks. Tables wider than
    ``resize_above`` columns are scaled to the text width (``\\resizebox``, graphicx)."""
    ncol = len(table.columns)
    resize = ncol > resize_above
    lines = ["% needs \\usepackage{booktabs}" + (", \\usepackage{graphicx}" if resize else "")]
    lines += ["\\begin{table}[ht]", "\\centering"]
    if table.caption:
        lines.append(f"\\caption{{{_latex_escape(table.caption)}}}")
    if label:
        lines.append(f"\\label{{{label}}}")
    if resize:
        lines.append("\\resizebox{\\textwidth}{!}{%")
    lines += [f"\\begin{{tabular}}{{{'r' * ncol}}}", "\\toprule"]
    # group header row (merged runs of equal group)
    runs: list[list] = []
    for s in table.spans:
        if runs and runs[-1][0] == s.group:
            runs[-1][1] += s.ncols
        else:
            runs.append([s.group, s.ncols])
    if any(g for g, _ in runs):
        cells, rules, col = [], [], 1
        for g, w in runs:
            title = _latex_escape(GROUP_TITLES.get(g, g))
            cells.append(f"\\multicolumn{{{w}}}{{c}}{{{title}}}" if w > 1 else title)
            if g:
                rules.append(f"\\cmidrule(lr){{{col}-{col + w - 1}}}")
            col += w
        lines.append(" & ".join(cells) + " \\\\")
        lines.append(" ".join(rules))
    cells = []
    for s in table.spans:
        head = s.latex if s.latex is not None else _latex_escape(s.label)
        cells.append(f"\\multicolumn{{{s.ncols}}}{{c}}{{{head}}}" if s.ncols > 1 else head)
    lines += [" & ".join(cells) + " \\\\", "\\midrule"]
    for i, row in enumerate(table.rows):
        if table.block_rows and i and i % table.block_rows == 0:
            lines.append("\\midrule")
        lines.append(" & ".join(_latex_escape(format_number(x, precision)) for x in row) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}"]
    if resize:
        lines.append("}")
    lines.append("\\end{table}")
    return "\n".join(lines) + "\n"


def _csv_cell(x: Cell) -> str:
    if x is None:
        return ""
    if isinstance(x, float | np.floating):
        return repr(float(x)) if math.isfinite(x) else str(float(x))
    return str(x)


def to_csv(table: Table) -> str:
    """CSV with the flat column names and numbers at full precision (``repr``)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(table.columns)
    for row in table.rows:
        w.writerow([_csv_cell(x) for x in row])
    return buf.getvalue()


def _parse_cell(text: str) -> Cell:
    if text == "":
        return None
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def parse_csv(text: str) -> tuple[tuple[str, ...], tuple[tuple[Cell, ...], ...]]:
    """Columns and rows of CSV text written by :func:`to_csv` (numbers parsed back)."""
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise UserError("csv: empty, expected a header row")
    return tuple(rows[0]), tuple(tuple(_parse_cell(c) for c in r) for r in rows[1:])


def read_csv(path: str | Path) -> tuple[tuple[str, ...], tuple[tuple[Cell, ...], ...]]:
    """Columns and rows of a CSV file written by :func:`write_table`."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"csv: no such file {str(p)!r}")
    return parse_csv(p.read_text("utf-8"))


def write_table(table: Table, out_dir: str | Path, stem: str, *, precision: int = 3) -> dict:
    """Write ``stem.md``, ``stem.csv`` and ``stem.tex`` into ``out_dir`` (atomically); returns
    the paths by format."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    # every number formatted once for the Markdown and the LaTeX (text passes through
    # format_number unchanged); the CSV keeps the numbers at full precision
    shown = dataclasses.replace(table, rows=tuple(
        tuple(format_number(x, precision) for x in row) for row in table.rows))
    for ext, text in (
        ("md", to_markdown(shown, precision=precision)),
        ("csv", to_csv(table)),
        ("tex", to_latex(shown, precision=precision, label=f"tab:{stem}")),
    ):
        path = out / f"{stem}.{ext}"
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text, "utf-8")
        tmp.replace(path)
        paths[ext] = path
    return paths
