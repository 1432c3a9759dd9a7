"""How the analysis report summarises a large arm (issue 46): above :data:`LARGE_N` coordinates
or :data:`LARGE_M` inputs, one row of the paper-shaped tables (Tables I, II, V-IX) has more than
a hundred columns at n = 9, so ``report.md`` gives instead, per transform,

* the relative residual ``||(P X^ - X)_ab||_F / ||X_ab||_F`` over all q of each per-segment
  block ab of M (or M⁻¹), D, G and A (:func:`block_lines`; rows: the coordinates of segment a,
  columns: those of segment b, for A the inputs of group b);
* the entries that contribute most to the residual (:func:`top_entry_lines`);
* the residual of each matrix at the first few q (:func:`per_q_lines`);

and the full tables stay in ``table_<transform>.csv``. :func:`panel_entries` chooses the at most
:data:`MAX_PANELS` entries of P(q) a figure draws; :func:`segment_blocks` and
:func:`input_blocks` group coordinates and inputs by segment (the rollout figures' inputs too).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from softpinn.bridge.figures.tables import percent_text

#: An arm with more coordinates than this gets the summarised report and figures.
LARGE_N = 4
#: An arm with more inputs than this too (a matrix table's row grows with n and m).
LARGE_M = 8
#: The most panels a figure of P(q)'s entries draws.
MAX_PANELS = 16
#: How many entries :func:`top_entry_lines` lists.
TOP_ENTRIES = 10
#: A share of a matrix's residual below this is rounding: such entries are not listed.
FLOOR = 1e-10

_LABEL = {"M": "M", "M_inv": "M⁻¹", "D": "D", "G": "G", "A": "A", "P": "P"}


def is_large(n: int, m: int = 0) -> bool:
    """Whether an arm of n coordinates and m inputs gets the summarised report."""
    return int(n) > LARGE_N or int(m) > LARGE_M


def segment_blocks(names: Sequence[str] | None, n: int) -> list[tuple[str, list[int]]]:
    """The coordinates grouped by segment, as (label, indices): consecutive names ending in the
    same number (``dx1, dy1, dL1`` -> segment 1, the spatial arm's eq. 12 ordering); without
    such names (or with one segment only) runs of three, labelled by their indices."""
    names = list(names) if names is not None and len(names) == n else None
    if names:
        ends = [re.search(r"(\d+)$", str(c)) for c in names]
        if all(ends):
            runs: list[tuple[str, list[int]]] = []
            for i, e in enumerate(ends):
                if runs and runs[-1][0] == e.group(1):
                    runs[-1][1].append(i)
                else:
                    runs.append((e.group(1), [i]))
            if len(runs) > 1 and len({s for s, _ in runs}) == len(runs):
                return [(f"segment {s} ({names[idx[0]]}–{names[idx[-1]]})"
                         if len(idx) > 1 else f"segment {s} ({names[idx[0]]})", idx)
                        for s, idx in runs]
    return [(f"q{i + 1}–q{min(i + 3, n)}" if min(i + 3, n) > i + 1 else f"q{i + 1}",
             list(range(i, min(i + 3, n)))) for i in range(0, n, 3)]


def segment_count(names: Sequence[str] | None, n: int) -> int:
    """How many segments the coordinate names tell (:func:`segment_blocks`); 1 when they tell
    none."""
    blocks = segment_blocks(names, n)
    return len(blocks) if blocks[0][0].startswith("segment") else 1


def input_blocks(m: int, segments: int) -> list[tuple[str, list[int]]]:
    """The inputs grouped by segment, as (label, indices): m / segments consecutive inputs each
    where that divides (a tendon arm's actuators per segment), else runs of four."""
    if m <= 0:
        return []
    size = m // segments if segments > 1 and m % segments == 0 else min(4, m)
    return [(f"u{i + 1}–u{min(i + size, m)}" if size > 1 else f"u{i + 1}",
             list(range(i, min(i + size, m)))) for i in range(0, m, size)]


def _mapped(result, true, learned, key: str):
    """The true matrix ``key`` and ``P X^`` at the q where P is defined (finite), as (N, n, c)."""
    P = np.asarray(result.P, float)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    X = np.asarray(true.block(key), float)[ok]
    return X, P[ok] @ np.asarray(learned.block(key), float)[ok]


def _rel(err: float, den: float) -> float:
    if den > 0:
        return err / den
    return 0.0 if err == 0 else float("inf")


def block_lines(result, true, learned, names: Sequence[str] | None) -> list[str]:
    """A Markdown table of the relative residual of every per-segment block of each matrix the
    transform was judged on, over all q (module docstring); ``–`` where a block of the true
    matrix and its error are both zero, ``true 0`` where only the true block is."""
    keys = [k for k in result.residual if true.has(k) and learned.has(k)]
    if not keys:
        return []
    n = true.n
    rows_of = segment_blocks(names, n)
    cols_of = {k: ([("", [0])] if k == "G" else
                   input_blocks(true.m, len(rows_of)) if k == "A" else rows_of) for k in keys}
    width = max(len(c) for c in cols_of.values())
    a_cols = cols_of.get("A") or []
    head = ["matrix", "rows"]
    for b in range(width):
        parts = [rows_of[b][0].split(" (")[0]] if b < len(rows_of) else []
        if b < len(a_cols):
            parts.append(f"A: {a_cols[b][0]}")
        head.append("; ".join(parts))
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k in keys:
        X, Y = _mapped(result, true, learned, k)
        for label, rows in rows_of:
            cells = []
            for _, cols in cols_of[k]:
                x, y = X[:, rows][:, :, cols], Y[:, rows][:, :, cols]
                err, den = float(np.linalg.norm(y - x)), float(np.linalg.norm(x))
                cells.append(("–" if err == 0 else "true 0") if den == 0 else
                             percent_text(err / den))
            cells += [""] * (width - len(cells))
            lines.append(f"| {_LABEL.get(k, k)} | {label} | " + " | ".join(cells) + " |")
    said = "the coordinates of segment b" + (", for A the inputs named" if a_cols else "")
    if "G" in keys:
        said += "; G, a vector, in the first column"
    return ["Relative residual of each block over all q, ‖(P X̂ − X)_ab‖ / ‖X_ab‖ (rows: the "
            f"coordinates of segment a; columns: {said}):", "", *lines, ""]


def top_entry_lines(result, true, learned, count: int = TOP_ENTRIES) -> list[str]:
    """A Markdown table of the ``count`` entries with the largest share of their matrix's
    residual, ``sqrt(sum_q (P X^ - X)_ij^2) / ||X||_F`` over all q (the squares of a matrix's
    shares add up to its residual squared), with their true and error rms over q; entries
    under :data:`FLOOR` (rounding) are left out."""
    found = []
    for k in result.residual:
        if not (true.has(k) and learned.has(k)):
            continue
        X, Y = _mapped(result, true, learned, k)
        if not len(X):
            continue
        norm = float(np.linalg.norm(X))
        err = np.sqrt(np.sum((Y - X) ** 2, axis=0))  # (n, c)
        rms_true = np.sqrt(np.mean(X ** 2, axis=0))
        for (i, j), e in np.ndenumerate(err):
            if not e == 0:  # NaN kept: an undefined entry is listed
                entry = f"{_LABEL.get(k, k)}[{i + 1}]" if k == "G" else (
                    f"{_LABEL.get(k, k)}[{i + 1},{j + 1}]")
                found.append((_rel(float(e), norm), entry, float(rms_true[i, j]),
                              float(e) / np.sqrt(len(X))))
    found = [f for f in found if not f[0] < FLOOR]
    if not found:
        return ["No entry's error is above rounding (each under "
                f"{100 * FLOOR:g} % of its matrix's norm).", ""]
    found.sort(key=lambda t: -t[0] if np.isfinite(t[0]) else -np.inf)
    lines = [f"The {min(count, len(found))} entries with the largest share of their matrix's "
             "residual, √Σ_q (P X̂ − X)²_ij / ‖X‖ over all q:", "",
             "| entry | share | true rms | error rms |", "|---|---|---|---|"]
    lines += [f"| {e} | {percent_text(s)} | {t:.3g} | {r:.3g} |"
              for s, e, t, r in found[:count]]
    return lines + [""]


def per_q_lines(result, q: np.ndarray, k: int) -> list[str]:
    """A Markdown table of the residual of each matrix at the first ``k`` q (one row per q)."""
    keys = list(result.residuals)
    q = np.asarray(q, float)
    lines = ["| # | q | " + " | ".join(_LABEL.get(x, x) for x in keys) + " |",
             "|" + "---|" * (2 + len(keys))]
    for i in range(min(k, len(q))):
        cells = [percent_text(result.residuals[x][i]) for x in keys]
        lines.append(f"| {i + 1} | " + ", ".join(f"{v:.3g}" for v in q[i]) + " | "
                     + " | ".join(cells) + " |")
    return lines + [""]


def panel_entries(results: Mapping[str, object], n: int,
                  limit: int = MAX_PANELS) -> list[tuple[int, int]]:
    """The entries (i, j) of P(q) a figure of at most ``limit`` panels draws: the diagonal, then
    the off-diagonal entries largest in rms over q and the transforms (finite values only);
    every entry where n² <= ``limit``."""
    if n * n <= limit:
        return [(i, j) for i in range(n) for j in range(n)]
    diag = [(i, i) for i in range(min(n, limit))]
    size = np.zeros((n, n))
    for r in results.values():
        P = np.asarray(r.P, float)
        ok = np.all(np.isfinite(P), axis=(1, 2))
        if ok.any():
            size = np.maximum(size, np.sqrt(np.mean(P[ok] ** 2, axis=0)))
    off = sorted(((i, j) for i in range(n) for j in range(n) if i != j),
                 key=lambda e: (-size[e], e))
    return diag + off[: limit - len(diag)]
