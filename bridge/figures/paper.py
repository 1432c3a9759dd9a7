"""The paper's tables as shipped (``paper_tables.json``, transcribed and corrected) and Table
III's row for a task beside ours."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from softpinn.bridge.figures.tables import Cell, Span, Table, format_mean_std
from softpinn.errors import UserError

# --------------------------------------------------------------------------------------------
# Table III: ours beside the paper


def load_paper_tables(path: str | Path | None = None) -> dict[str, Any]:
    """The paper's tables as transcribed (``paper_tables.json`` shipped with this package)."""
    if path is None:
        text = Path(__file__).with_name("paper_tables.json").read_text("utf-8")
    else:
        p = Path(path)
        if not p.is_file():
            raise UserError(f"paper tables: no such file {str(p)!r}")
        text = p.read_text("utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise UserError(f"paper tables {path or 'paper_tables.json'}: not JSON ({exc})") from exc


_TABLE_III_COLUMNS = (
    "source",
    "model",
    "timestep",
    "model size",
    "samples",
    "epochs",
    "train error",
    "test error",
    "prediction error (horizon)",
)
_KINDS = {"blackbox": "black-box", "physics": "physics-based"}


def _table_iii_entry(
    entry: Mapping[str, Any] | None, variant: str | None, timestep_s: float | None = None
) -> list[Cell]:
    if not entry:
        return ["—"] * 7
    ts = entry.get("timestep_s", timestep_s)
    timestep = f"{ts:g}s" if ts is not None else None
    if timestep is None:
        timestep = variant or "—"

    def err(key):
        e = entry.get(key)
        if not e:
            return "—"
        return format_mean_std(e.get("mean"), e.get("std"), horizon_s=e.get("horizon_s"))

    model = entry.get("model", "—")
    if "network" in entry and entry["network"]:
        model = f"{model} ({entry['network']})"
    return [
        timestep,
        model,
        entry.get("samples", "—"),
        entry.get("epochs", "—"),
        err("train_error"),
        err("test_error"),
        err("prediction_error"),
    ]


def paper_task(task: str) -> bool:
    """Whether the paper's Table III has a row for ``task`` (a spec of the user's has none)."""
    try:
        table = load_paper_tables()["table_III"]
    except (UserError, KeyError):
        return False
    return task in table


def results_table(ours: Mapping[str, Mapping[str, Any]], *, caption: str = "") -> Table:
    """Table III's columns for a task the paper does not have (a user's own arm): our rows
    only, ``ours`` as in :func:`table_iii_comparison`."""
    for kind in ours:
        if kind not in _KINDS:
            raise UserError(f"ours: unknown model kind {kind!r}; expected {list(_KINDS)}")
    rows = [tuple(["ours", title] + _table_iii_entry(ours[kind], None))
            for kind, title in _KINDS.items() if kind in ours]
    return Table(tuple(Span("", c) for c in _TABLE_III_COLUMNS), tuple(rows), caption=caption)


def table_iii_comparison(
    task: str,
    ours: Mapping[str, Mapping[str, Any]],
    *,
    variant: str | None = None,
    paper: Mapping[str, Any] | None = None,
    caption: str = "",
) -> Table:
    """Table III's row for ``task`` (``task1`` ... ``task5``; Task 5 needs ``variant``, one of
    ``fixed_0.0002s``, ``50Hz``, ``100Hz``, ``1000Hz``) beside ours.

    ``ours`` maps ``"blackbox"`` and/or ``"physics"`` to dicts with the keys of
    ``paper_tables.json``: ``timestep_s``, ``model``, ``samples``, ``epochs``, ``train_error``,
    ``test_error``, ``prediction_error`` (each ``{"mean", "std"}``, the last with
    ``"horizon_s"``), optionally ``network``.
    """
    paper = load_paper_tables() if paper is None else paper
    table = paper.get("table_III", paper)
    tasks = [k for k in table if k.startswith("task")]
    if task not in tasks:
        raise UserError(f"task: expected one of {tasks}, got {task!r}")
    row = table[task]
    for kind in ours:
        if kind not in _KINDS:
            raise UserError(f"ours: unknown model kind {kind!r}; expected {list(_KINDS)}")
    rows = []
    # Table III prints the time step once per task, in the black-box column
    shared_ts = (row.get("blackbox") or {}).get("timestep_s")
    for kind, title in _KINDS.items():
        entry = row.get(kind)
        if entry is not None and variant is None and "model" not in entry:
            raise UserError(
                f"variant: {task} has several columns in Table III, choose one of {list(entry)}"
            )
        if entry is not None and variant is not None and "model" not in entry:
            entry = entry.get(variant)
        rows.append(tuple(["paper", title] + _table_iii_entry(entry, variant, shared_ts)))
        if kind in ours:
            rows.append(tuple(["ours", title] + _table_iii_entry(ours[kind], variant)))
    spans = tuple(Span("", c) for c in _TABLE_III_COLUMNS)
    cap = caption or f"{task} ({row.get('system', '')}): the paper's Table III and ours"
    return Table(spans, tuple(rows), caption=cap)


