"""Reports of large arms stay readable (issue 46): at n = 9, m = 12 ``analyze``'s report.md
summarises each transform by per-segment blocks, the entries that contribute most and the first
q, the full tables kept in CSV; the P(q) figure draws at most 16 entries; a rollout figure draws
each segment's inputs in a panel of its own. A small arm's report is the paper-shaped one."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from softpinn.bridge.analysis import analyze, sample_q
from softpinn.bridge.figures import analysis as analysis_figures
from softpinn.bridge.figures.large_arms import (
    MAX_PANELS,
    input_blocks,
    is_large,
    panel_entries,
    segment_blocks,
)
from softpinn.bridge.figures.tables import percent_text, read_csv, to_markdown, transform_table


def _arm(segments: int, N: int = 24, seed: int = 0, per_segment: int = 3, inputs: int = 4):
    """Evaluated matrices of a made-up arm of ``segments`` segments (``per_segment``
    coordinates and ``inputs`` inputs each) and a learned model P(q)⁻¹ times them, P(q) =
    (I + tanh(q) W) / 2, analysed with every transform; coordinates named as a spatial arm's
    (dx1, dy1, dL1, ...)."""
    n, m = per_segment * segments, inputs * segments
    rng = np.random.default_rng(seed)
    B, C = rng.normal(size=(n, n)), rng.normal(size=(n, n))
    M0, D0 = B @ B.T / n + np.eye(n), C @ C.T / n + 0.1 * np.eye(n)
    K, A0 = np.diag(rng.uniform(1, 5, n)), rng.normal(size=(n, m))
    W = rng.normal(scale=0.05, size=(n, n))
    q = sample_q([-0.5] * n, [0.5] * n, N, seed=seed)
    s = np.sin(q)
    M = M0 + 0.2 * np.einsum("ni,nj->nij", s, s)
    true = {"M": M, "M_inv": np.linalg.inv(M), "D": np.broadcast_to(D0, M.shape).copy(),
            "G": q @ K.T + 0.3 * s, "A": A0 * (1 + 0.1 * np.cos(q))[:, :, None]}
    Pinv = np.linalg.inv(0.5 * (np.eye(n) + np.tanh(q)[:, :, None] * W))
    learned = {k: Pinv @ true[k] for k in ("M", "D", "A")}
    learned["G"] = np.einsum("nij,nj->ni", Pinv, true["G"])
    learned["M_inv"] = np.linalg.inv(learned["M"])
    result = analyze(true, learned, q)
    names = ["dx", "dy", "dL"][:per_segment]
    names = [f"{c}{i + 1}" for i in range(segments) for c in names]
    return dataclasses.replace(result, meta=dict(result.meta, coordinates=names,
                                                 model_kind="spatial-pcc"))


@pytest.fixture(scope="module")
def large():
    return _arm(3)


def _table_widths(text: str) -> list[int]:
    """Cells per Markdown table row (escaped bars are not separators)."""
    return [len(re.split(r"(?<!\\)\|", line.strip())) - 2 for line in text.splitlines()
            if line.startswith("|")]


def test_a_large_arm_report_is_summarised_and_its_tables_kept_in_csv(large, tmp_path,
                                                                     monkeypatch):
    assert (large.true.n, large.true.m) == (9, 12) and is_large(9, 12)
    drawn = []
    original = analysis_figures.plot_transform_entries

    def spy(*args, **kw):
        fig = original(*args, **kw)
        drawn.append([ax.get_title() for ax in fig.axes if ax.get_visible()])
        return fig

    monkeypatch.setattr(analysis_figures, "plot_transform_entries", spy)
    paths = analysis_figures.write_report(large, tmp_path, max_table_q=3)
    report = paths["report.md"].read_text()
    assert len(report.encode()) < 30_000
    assert max(_table_widths(report)) <= 15
    # every transform's full table (each entry at each q) in CSV, linked; no 100-column md/tex
    for name in large.results:
        assert f"[`table_{name}.csv`](table_{name}.csv)" in report
        assert f"table_{name}.md" not in paths and f"table_{name}.tex" not in paths
        assert not (tmp_path / f"table_{name}.md").exists()
    full = transform_table(large.q, large.true, large.learned, large.results["alpha"],
                           matrices=("M", "D", "G", "A"))
    columns, rows = read_csv(paths["table_alpha.csv"])
    assert columns == full.columns and len(columns) > 100 and len(rows) == 9 * len(large.q)
    c = columns.index("true A[12]")
    np.testing.assert_array_equal([row[c] for row in rows], large.true.A[:, :, 11].ravel())
    # the figure of P(q): at most 16 panels, the diagonal among them, and the report says so
    (titles,) = drawn
    assert len(titles) <= MAX_PANELS
    assert {f"P[{i},{i}]" for i in range(1, 10)} <= set(titles)
    assert f"draws {len(titles)} of the 81 entries of P(q)" in report


def test_the_block_table_and_top_entries_are_the_residuals_of_their_entries(large, tmp_path):
    paths = analysis_figures.write_report(large, tmp_path, plots=False)
    report = paths["report.md"].read_text()
    section = report.split("## alpha")[1].split("\n## ")[0]
    r = large.results["alpha"]
    X, Y = large.true.M, r.P @ large.learned.M
    blocks = segment_blocks(large.meta["coordinates"], 9)
    assert [lab for lab, _ in blocks][0] == "segment 1 (dx1–dL1)"
    (_, rows), (_, cols) = blocks[0], blocks[2]  # segment 1's rows, segment 3's columns
    x, y = X[:, rows][:, :, cols], Y[:, rows][:, :, cols]
    line = next(x for x in section.splitlines() if x.startswith("| M | segment 1"))
    assert line.rstrip(" |").split(" | ")[4] == percent_text(
        np.linalg.norm(y - x) / np.linalg.norm(x))
    # the top entry: the largest share of any matrix's residual, each share computed here
    shares = {}
    for k in r.residual:
        Xk, Yk = large.true.block(k), r.P @ large.learned.block(k)
        e = np.sqrt(np.sum((Yk - Xk) ** 2, axis=0)) / np.linalg.norm(Xk)
        for (i, j), v in np.ndenumerate(e):
            shares[f"{k}[{i + 1}]" if k == "G" else f"{k}[{i + 1},{j + 1}]"] = v
    best = max(shares, key=shares.get)
    table = section.split("| entry | share |")[1].splitlines()[2]
    assert table.startswith(f"| {best} | {percent_text(shares[best])} |")
    # the first q: each matrix's residual at q_1, as the transform computed it
    row = next(x for x in section.splitlines() if x.startswith("| 1 | "))
    assert row.endswith(" | ".join(percent_text(r.residuals[k][0]) for k in r.residuals) + " |")


def test_a_small_arm_keeps_the_paper_shaped_report(tmp_path, monkeypatch):
    small = _arm(1, N=10, per_segment=2, inputs=2)  # n = 2, m = 2
    assert not is_large(2, 2)
    drawn = []
    original = analysis_figures.plot_transform_entries

    def spy(*args, **kw):
        drawn.append(kw.get("entries"))
        return original(*args, **kw)

    monkeypatch.setattr(analysis_figures, "plot_transform_entries", spy)
    paths = analysis_figures.write_report(small, tmp_path, max_table_q=3)
    report = paths["report.md"].read_text()
    assert "here by blocks" not in report and "entries of P(q):" not in report
    for name, r in small.results.items():
        assert paths[f"table_{name}.md"].is_file() and paths[f"table_{name}.tex"].is_file()
        table = transform_table(small.q, small.true, small.learned, r,
                                matrices=("M", "D", "G", "A"))
        first = dataclasses.replace(table, rows=table.rows[:3 * 2], caption="")
        assert f"First 3 of 10 q (all q in `table_{name}.csv`):\n\n" in report
        assert to_markdown(first) in report
    assert drawn == [None]  # every entry of P(q), in an n x n grid


def test_segments_and_input_groups():
    names = ["dx1", "dy1", "dL1", "dx2", "dy2", "dL2"]
    assert segment_blocks(names, 6) == [("segment 1 (dx1–dL1)", [0, 1, 2]),
                                        ("segment 2 (dx2–dL2)", [3, 4, 5])]
    # without segment numbers (or with names that repeat one): runs of three coordinates
    assert segment_blocks(None, 5) == [("q1–q3", [0, 1, 2]), ("q4–q5", [3, 4])]
    assert segment_blocks(["q1", "q2", "q3", "q4", "q5"], 5)[1][1] == [1]  # one per q
    assert [lab for lab, _ in input_blocks(12, 3)] == ["u1–u4", "u5–u8", "u9–u12"]
    assert [idx for _, idx in input_blocks(10, 3)] == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]]
    assert input_blocks(0, 3) == []


def test_panel_entries_are_the_diagonal_then_the_largest_off_diagonal():
    rng = np.random.default_rng(1)
    P = np.tile(np.eye(9), (5, 1, 1)) + 1e-3 * rng.normal(size=(5, 9, 9))
    P[:, 7, 2] = 0.5  # the largest off-diagonal entry
    P[2, 0, 4] = np.nan  # non-finite values are left out of the ranking, not propagated
    result = type("R", (), {"P": P})()
    entries = panel_entries({"x": result}, 9)
    assert len(entries) == 16 and entries[:9] == [(i, i) for i in range(9)]
    assert entries[9] == (7, 2)
    assert panel_entries({"x": type("R", (), {"P": P[:, :4, :4]})()}, 4) == [
        (i, j) for i in range(4) for j in range(4)]


def test_a_rollout_figure_draws_each_segments_inputs_in_a_panel(tmp_path, monkeypatch):
    from softpinn.bridge.figures import rollouts

    drawn = []
    original = rollouts.save_for_print

    def spy(fig, path, **kw):
        drawn.append([(ax.get_title(loc="left"), [line.get_label() for line in ax.get_lines()],
                       [line.get_color() for line in ax.get_lines()]) for ax in fig.axes])
        return original(fig, path, **kw)

    monkeypatch.setattr(rollouts, "save_for_print", spy)
    t = np.linspace(0.0, 2.0, 100)
    q = np.stack([np.sin((i + 1) * t) for i in range(9)], axis=1)
    u = np.stack([np.cos((j + 1) * t) for j in range(12)], axis=1)
    names = [f"{c}{s}" for s in (1, 2, 3) for c in ("dx", "dy", "dL")]
    path = rollouts.rollout_figure(t, q, {"lagrangian": q + 1e-3}, u=u, names=names,
                                   units=["m"] * 9, title="n = 9", path=tmp_path / "r.png")
    assert path.is_file()
    (axes,) = drawn
    inputs = [(title, labels, colors) for title, labels, colors in axes
              if labels and all(lab.startswith("u") for lab in labels)]
    assert [title for title, _, _ in inputs] == [
        "inputs of segment 1 (u1–u4)", "inputs of segment 2 (u5–u8)",
        "inputs of segment 3 (u9–u12)"]
    assert [labels for _, labels, _ in inputs] == [
        [f"u{j}" for j in range(s, s + 4)] for s in (1, 5, 9)]
    assert all(len(set(colors)) == len(colors) for _, _, colors in inputs)


def test_predicts_rollout_plot_tells_twelve_coordinates_errors_apart(tmp_path, monkeypatch):
    """``softpinn predict``'s figure draws every coordinate's error in one panel: past ten
    (a 4-segment arm) a linestyle tells the ones of a repeated colour apart."""
    from softpinn.learn import plots

    drawn = []
    original = plots._save

    def spy(fig, path, record=False):
        drawn.append([[(line.get_color(), line.get_linestyle()) for line in ax.get_lines()]
                      for ax in fig.axes])
        return original(fig, path, record)

    monkeypatch.setattr(plots, "_save", spy)
    t = np.linspace(0.0, 1.0, 50)
    q = np.stack([np.sin((i + 1) * t) for i in range(12)], axis=1)
    names = [f"{c}{s}" for s in (1, 2, 3, 4) for c in ("dx", "dy", "dL")]
    assert plots.plot_rollout(t, q, q + 1e-3, tmp_path / "r.png", names=names).is_file()
    errors = drawn[0][-1]
    assert len(errors) == 12 and len(set(errors)) == 12
