"""bridge.tables: paper-shaped tables in Markdown, CSV and LaTeX, and Table III beside ours."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from softpinn.bridge.analysis.transform_result import match_word
from softpinn.bridge.analysis.transforms import fit_joint, fit_smooth, fit_transform
from softpinn.bridge.figures.paper import load_paper_tables, table_iii_comparison
from softpinn.bridge.figures.tables import (
    format_mean_std,
    format_number,
    matrix_table,
    parse_csv,
    read_csv,
    summary_table,
    to_csv,
    to_latex,
    to_markdown,
    transform_table,
    write_table,
)
from softpinn.errors import UserError

TASK4_ROW = {  # Table I, q = [1.2, -0.2, 0.15], mathematical model
    "M": [[1.728e-03, -3.121e-05, -1.957e-03], [-3.121e-05, 1.546e-03, 3.261e-04],
          [-1.957e-03, 3.261e-04, 9.286e-02]],
    "D": [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]],
    "G": [1.293, -0.216, -1.149],
    "A": [[-0.037, -0.993, 0.065], [0.777, 0.037, -0.011], [0.0, 0.0, 0.771]],
}  # fmt: skip


def random_stacks(N=4, n=3, m=2, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1, 1, (N, n))
    B = rng.standard_normal((N, n, n))
    true = {
        "M": B @ np.swapaxes(B, 1, 2) + n * np.eye(n),
        "D": np.broadcast_to(0.1 * np.eye(n), (N, n, n)).copy(),
        "G": rng.standard_normal((N, n)),
        "A": rng.standard_normal((N, n, m)),
    }
    P = np.eye(n) * 2 + 0.1 * rng.standard_normal((N, n, n))
    Pinv = np.linalg.inv(P)
    learned = {k: Pinv @ v for k, v in true.items() if k != "G"}
    learned["G"] = (Pinv @ true["G"][:, :, None])[:, :, 0]
    return q, true, learned


@pytest.mark.parametrize(
    ("x", "precision", "text"),
    [
        (1.293, 3, "1.293"),
        (1.728e-03, 3, "1.728e-03"),
        (600.3234, 3, "600.323"),
        (-0.0371, 3, "-0.037"),
        (9.286e-02, 3, "0.093"),
        (0.0, 3, "0.000"),
        (12345.678, 2, "1.23e+04"),
        (3.14159265, 5, "3.14159"),
        (41599, 3, "41599"),
        ("lagrangian", 3, "lagrangian"),
        (float("nan"), 3, "nan"),
        (None, 3, ""),
    ],
)
def test_format_number(x, precision, text):
    assert format_number(x, precision) == text


def test_format_mean_std_like_table_iii():
    assert format_mean_std(5.969e-08, 1.69e-07) == "5.969e-08 ± 1.69e-07"
    assert format_mean_std(0.171, 0.272, horizon_s=5.0) == "0.171 ± 0.272 (5s)"
    assert format_mean_std(2.001, None, horizon_s=2.7) == "2.001 ± inf (2.7s)"
    assert format_mean_std(9.723e-04, 1.33e-02) == "9.723e-04 ± 1.33e-02"


def test_matrix_table_layout_like_table_i():
    q = np.array([[1.2, -0.2, 0.15]])
    mats = [("true", k, np.array([TASK4_ROW[k]])) for k in ("M", "D", "G", "A")]
    t = matrix_table(q, mats)
    assert t.columns[:5] == ("q", "true M[1]", "true M[2]", "true M[3]", "true D[1]")
    assert "true G" in t.columns and len(t.columns) == 1 + 3 + 3 + 1 + 3
    assert len(t.rows) == 3 and t.block_rows == 3
    # row r: q_r, row r of M, D, G, A
    assert t.rows[1][0] == -0.2 and t.rows[1][1:4] == tuple(TASK4_ROW["M"][1])
    md = to_markdown(t, precision=3)
    for text in ("| 1.200<br>-0.200<br>0.150 | 1.728e-03<br>", "<br>0.093 |", "0.777"):
        assert text in md
    tex = to_latex(t, precision=3, label="tab:one")
    assert "\\toprule" in tex and "\\bottomrule" in tex and "\\label{tab:one}" in tex
    assert "1.200 & 1.728e-03 & -3.121e-05 & -1.957e-03 & 0.100 & 0.000" in tex
    assert tex.count("\\\\") == 3 + 2  # three rows, group header, matrix header


def test_precision_is_respected():
    t = matrix_table(np.array([[0.123456789]]), [("true", "M", np.array([[[3.14159265358]]]))])
    assert "| 0.12346 | 3.14159 |" in to_markdown(t, precision=5)
    assert "0.1 & 3.1 \\\\" in to_latex(t, precision=1)
    assert "3.14159265358" in to_csv(t)


def test_csv_round_trip(tmp_path):
    q, true, learned = random_stacks()
    res = fit_joint(true, learned, q)
    t = transform_table(q, true, learned, res, caption="like Table I")
    columns, rows = parse_csv(to_csv(t))
    assert columns == t.columns
    assert rows == t.rows  # repr round-trips every float exactly
    paths = write_table(t, tmp_path / "out", "table_I", precision=4)
    assert sorted(p.suffix for p in paths.values()) == [".csv", ".md", ".tex"]
    assert read_csv(paths["csv"]) == (t.columns, t.rows)
    md = paths["md"].read_text()
    assert "**like Table I**" in md and format_number(float(q[0, 0]), 4) in md
    assert not list((tmp_path / "out").glob("*.tmp"))


def test_transform_table_holds_P_and_transformed():
    q, true, learned = random_stacks(N=3, n=3, m=2)
    res = fit_joint(true, learned, q)
    t = transform_table(q, true, learned, res)
    cols = t.columns
    assert "transformed A[2]" in cols and "P joint[3]" in cols and "learned G" in cols
    arr = np.array([[np.nan if isinstance(x, str) else x for x in r] for r in t.rows])
    i = cols.index("transformed M[1]")
    np.testing.assert_allclose(arr[:, i : i + 3].reshape(3, 3, 3), true["M"], atol=1e-12)
    j = cols.index("P joint[1]")
    np.testing.assert_allclose(arr[:, j : j + 3].reshape(3, 3, 3), res.P)
    tex = to_latex(t)
    assert "$\\hat{M}(q)$" in tex and "$P\\hat{G}$" in tex and "\\cmidrule" in tex
    assert "\\resizebox{\\textwidth}" in tex  # 34 columns are scaled to the page


def test_alpha_table_has_alpha_per_q_like_table_vi(tmp_path):
    q, true, _ = random_stacks(N=3)
    scale = np.array([0.3, 0.32, 0.35])
    learned = {k: v * scale.reshape((3,) + (1,) * (v.ndim - 1)) for k, v in true.items()}
    res = fit_transform("alpha", true, learned, q)
    t = transform_table(q, true, learned, res)
    assert t.columns[-1] == "alpha at q"
    np.testing.assert_allclose([r[-1] for r in t.rows[::3]], [0.3, 0.32, 0.35], rtol=1e-12)
    assert all(r[-1] is None for i, r in enumerate(t.rows) if i % 3)
    assert "$\\alpha(q)$" in to_latex(t)
    assert read_csv(write_table(t, tmp_path, "vi")["csv"]) == (t.columns, t.rows)


def test_hamiltonian_table_shows_M_inv_without_transform():
    q, true, learned = random_stacks(N=2)
    true["M_inv"] = np.linalg.inv(true.pop("M"))
    learned["M_inv"] = np.linalg.inv(learned.pop("M"))
    t = transform_table(q, true, learned, None, matrices=("M_inv", "D", "G", "A"))
    assert "true M_inv[1]" in t.columns and "learned M_inv[3]" in t.columns
    assert not any(c.startswith("P") or c.startswith("transformed") for c in t.columns)
    assert "$M^{-1}(q)$" in to_latex(t)


def test_summary_table_lists_each_transform():
    q, true, learned = random_stacks(N=12)
    results = {n: fit_transform(n, true, learned, q) for n in ("pointwise", "alpha", "direct")}
    results["smooth"] = fit_smooth(true, learned, q, degree=1)
    t = summary_table(results)
    assert [r[0] for r in t.rows] == ["pointwise", "alpha", "direct", "smooth"]
    c = t.columns
    row = dict(zip(c, t.rows[1], strict=True))
    assert row["P ~ cI alpha"] == pytest.approx(results["alpha"].params["alpha"])
    assert row["residual M (%)"] == pytest.approx(100 * results["alpha"].residual["M"])
    assert row["residual total (%)"] == pytest.approx(100 * results["alpha"].residual_total)
    assert row["match"] == match_word(results["alpha"].residual_total)
    held = dict(zip(c, t.rows[3], strict=True))["held-out residual (%)"]
    assert held == pytest.approx(100 * max(results["smooth"].params["residual_heldout"].values()))
    md = to_markdown(t)
    assert "| pointwise | ok | recovered |" in md  # P = M M̂⁻¹ explains M exactly
    assert "success" not in md


def test_match_word_says_what_a_residual_means():
    assert match_word(0.0) == match_word(0.03) == "recovered"
    assert match_word(0.0301) == match_word(0.15) == "approximate"
    assert match_word(3.86) == "not recovered"  # was printed as "success" beside 3.86
    assert match_word(None) == match_word(float("nan")) == match_word(float("inf")) == "undefined"


def test_block_tables_keep_each_q_on_one_markdown_row():
    q = np.array([[1.5, 1.0], [0.3, 0.2]])
    M = np.array([[[1.0, 2.0], [2.0, 5.0]], [[3.0, 0.5], [0.5, 4.0]]])
    t = matrix_table(q, [("true", "M", M)])
    md = to_markdown(t).splitlines()
    body = md[2:]
    assert len(body) == 2  # two q, no blank separator rows
    assert body[0] == "| 1.500<br>1.000 | 1.000<br>2.000 | 2.000<br>5.000 |"
    assert all(line.strip("| ") for line in body)


def test_table_iii_comparison_puts_paper_numbers_in():
    paper = load_paper_tables()
    shipped = Path(__file__).parents[1] / "bridge" / "figures" / "paper_tables.json"
    ref = json.loads(shipped.read_text())
    assert paper == ref
    ours = {
        "physics": {
            "timestep_s": 0.02,
            "model": "(4*2)*2 + 4*2",
            "network": "lagrangian",
            "samples": 10000,
            "epochs": 600,
            "train_error": {"mean": 1.0e-07, "std": 2.0e-07},
            "test_error": {"mean": 3.0e-07, "std": 4.0e-07},
            "prediction_error": {"mean": 1.5e-04, "std": 6.0e-06, "horizon_s": 2.7},
        }
    }
    t = table_iii_comparison("task1", ours, paper=paper)
    assert [r[:2] for r in t.rows] == [
        ("paper", "black-box"),
        ("paper", "physics-based"),
        ("ours", "physics-based"),
    ]
    md = to_markdown(t)
    p = paper["table_III"]["task1"]["physics"]
    assert "| paper | physics-based | 0.02s | (4*2)*2 + 4*2 (lagrangian) | 10000 | 6000 |" in md
    assert format_mean_std(p["train_error"]["mean"], p["train_error"]["std"]) in md
    assert "5.969e-08 ± 1.69e-07" in md and "5.172e-08 ± 1.23e-07" in md
    assert "1.303e-04 ± 5.32e-06 (2.7s)" in md and "2.001 ± inf (2.7s)" in md
    assert "| ours | physics-based | 0.02s |" in md and "1.000e-07 ± 2.00e-07" in md
    tex = to_latex(t)
    assert "5.969e-08 $\\pm$ 1.69e-07" in tex
    # Task 5 has one column per data set
    t5 = table_iii_comparison("task5", {}, variant="1000Hz", paper=paper)
    assert "1.822e-07 ± 6.67e-06" in to_markdown(t5)
    assert t5.rows[0][2:] == ("—",) * 7  # no black-box model at 1000 Hz in the paper


def test_our_epochs_cell_counts_an_lbfgs_finish():
    from softpinn.bridge.report.task import _epochs

    assert _epochs({"epochs": 400, "config": {"lbfgs_steps": 200}}) == "400 + 200 L-BFGS"
    assert _epochs({"epochs": 400, "config": {"lbfgs_steps": 0}}) == 400
    ours = {"physics": {"model": "m", "epochs": _epochs(
        {"epochs": 400, "config": {"lbfgs_steps": 200}})}}
    assert "| m | — | 400 + 200 L-BFGS |" in to_markdown(table_iii_comparison("task3", ours))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"task": "task9", "ours": {}}, "task: expected one of"),
        ({"task": "task5", "ours": {}}, "variant: task5 has several columns"),
        ({"task": "task1", "ours": {"lnn": {}}}, "unknown model kind 'lnn'"),
    ],
)
def test_table_iii_bad_input(kwargs, match):
    with pytest.raises(UserError, match=match):
        table_iii_comparison(**kwargs)


def test_bad_shapes_and_files(tmp_path):
    with pytest.raises(UserError, match=r"true M: expected shape \(2, 3, c\)"):
        matrix_table(np.zeros((2, 3)), [("true", "M", np.zeros((2, 2, 2)))])
    with pytest.raises(UserError, match="no such file"):
        read_csv(tmp_path / "missing.csv")
    with pytest.raises(UserError, match="no such file"):
        load_paper_tables(tmp_path / "missing.json")


def test_epochs_column_says_when_training_stopped_early():
    """Table III's epochs column: the epochs run where early stopping (a recipe's patience)
    ended a run sooner, else the budget, with L-BFGS iterations after them."""
    from softpinn.bridge.report.task import _epochs

    def trained(planned, ran, lbfgs=0):
        return {"epochs": planned, "config": {"lbfgs_steps": lbfgs},
                "metrics": {"members": [{"epochs_run": r} for r in ran]}}

    assert _epochs(trained(40, [40])) == 40
    assert _epochs(trained(40, [13])) == "13 of 40 (early stop)"
    assert _epochs(trained(40, [13, 22])) == "13-22 of 40 (early stop)"
    assert _epochs(trained(400, [400], 2000)) == "400 + 2000 L-BFGS"
    assert _epochs(trained(400, [120], 2000)) == "120 of 400 (early stop) + 2000 L-BFGS"


def test_rollouts_that_ran_away_are_counted_beside_inf():
    """A mean of inf says a rollout ran away; the report says how many, and the others' error."""
    import math

    from softpinn.bridge.figures.task import _ran_away_text
    from softpinn.bridge.tasks.measure_stages import error_stats

    s = error_stats([np.array([0.1, 0.3, math.inf, 0.2])])
    assert s["mean"] == math.inf and s["std"] == math.inf
    assert s["ran_away"]["count"] == 1 and s["ran_away"]["of"] == 4
    assert s["ran_away"]["others"]["mean"] == pytest.approx(0.2)
    assert s["ran_away"]["others"]["std"] == pytest.approx(np.std([0.1, 0.3, 0.2]))
    assert _ran_away_text(s["ran_away"]) == "; 1 of 4 ran away, the other 3: 0.200 ± 0.082"
    # over seeds: every rollout of every seed counts
    two = error_stats([np.array([0.1, math.inf]), np.array([0.3, 0.5])])
    assert two["ran_away"] == {"count": 1, "of": 4, "others": pytest.approx(
        {"mean": 0.3, "std": float(np.std([0.1, 0.3, 0.5]))})}
    assert _ran_away_text(error_stats([np.array([math.inf, 1.0])])["ran_away"]) == \
        "; 1 of 2 ran away, the other: 1.000 ± 0.000"
    gone = error_stats([np.array([math.inf, math.inf])])
    assert gone["ran_away"] == {"count": 2, "of": 2}
    assert _ran_away_text(gone["ran_away"]) == "; 2 of 2 ran away"
    fine = error_stats([np.array([0.1, 0.3])])
    assert "ran_away" not in fine and _ran_away_text(fine.get("ran_away")) == ""
    assert fine["mean"] == pytest.approx(0.2)


def test_percent_text_reads_at_a_glance():
    from softpinn.bridge.figures.tables import percent_text

    assert percent_text(0.21) == "21 %"
    assert percent_text(0.0035) == "0.35 %"
    assert percent_text(1.0) == "100 %"
    assert percent_text(14.0) == "1,400 %"
    assert percent_text(1.7e-16) == "0 %"
    assert percent_text(2e-7) == "2.0e-05 %"
    assert percent_text(None) == percent_text(float("nan")) == "–"


def test_the_no_forces_baseline_is_explained_for_momenta():
    """On (q, p) the no-forces baseline is handed q̇ = M⁻¹ p: the report says so beside a
    Hamiltonian network's floor, and not for models on velocities alone."""
    from softpinn.bridge.report.task import _floor_lines

    def entry(state):
        return {"floor": {"mean": 1e-9, "state": state, "no_forces": 5e-7},
                "predict": {"test_error": {"mean": 1e-6}}}

    text = " ".join(_floor_lines({"hamiltonian": entry("momentum"),
                                  "blackbox": entry("velocity")}))
    assert "handed the recorded velocity q̇ = M⁻¹ p" in text
    assert "handed" not in " ".join(_floor_lines({"lagrangian": entry("velocity")}))


def _comparison(linear: tuple[float, float], still: float, arx_out=()):
    """No motion and the two linear models at 1 s and 5 s: ARX ``linear`` (1 s, 5 s), the
    linear second-order model ten times worse, no motion ``still`` at both."""
    from softpinn.bridge.analysis.baselines import BaselineComparison, BaselineScore

    scores = []
    for name, kind, factor in (("no motion", "no_motion", None), ("ARX (order 2)", "arx", 1.0),
                               ("linear 2nd order", "linear2", 10.0)):
        for h, lin in zip((1.0, 5.0), linear, strict=True):
            mean = still if factor is None else factor * lin
            out = tuple(arx_out) if kind == "arx" else ()
            scores.append(BaselineScore(name, kind, h, mean, 0.1 * mean, out))
    return BaselineComparison((0, 1, 2), (4, 5), tuple(scores))


def test_the_verdict_names_the_winner_at_each_horizon():
    """Issue 43: one line says whether a network beats the best linear model and no motion at
    each horizon, and names whom it loses to."""
    from softpinn.bridge.analysis.baselines import verdict

    c = _comparison(linear=(1e-4, 1e-2), still=1e-3)
    assert c.best_linear(5.0).name == "ARX (order 2)"
    line = verdict("Lagrangian network", {1.0: 1e-5, 5.0: 2e-2}, c)
    first, second = line.split("; ")
    assert first == ("Lagrangian network: at 1 s beats the best linear model (ARX (order 2)) "
                     "by 10.0x and no motion by 100x")
    # at 5 s no motion (1e-3) is better than ARX (1e-2): the network loses to no motion
    assert second == "at 5 s LOSES to no motion (its error is 20.0x no motion's)"
    # within 1 %, a win or a loss reads as the tie it is (1.004: "1.00x", never "1x")
    assert verdict("x", {1.0: 1e-4 / 1.004}, c).endswith("by 1.00x (within 1 %: a tie) and "
                                                         "no motion by 10.0x")
    # beating the linear model but not no motion is a loss, to no motion
    line = verdict("black box", {5.0: 5e-3}, c)
    assert "LOSES to no motion" in line and "beats" not in line
    # a diverged rollout loses
    assert "LOSES" in verdict("black box", {1.0: math.inf}, c)


def test_baseline_rows_and_verdict_lines_read_from_the_stage_json(tmp_path):
    """The report rebuilds the comparison from results.json (inf stored as null) and shows the
    networks first, then the baselines, with rollouts that left the training range said."""
    from softpinn.bridge.analysis.baselines import BaselineComparison
    from softpinn.bridge.report.baselines import baseline_table, verdict_lines

    c = _comparison(linear=(1e-4, 1e-2), still=1e-3, arx_out=(5,))
    stored = json.loads(json.dumps(c.to_json()))
    stored["scores"][-1]["mean"] = None  # linear 2nd order diverged at 5 s
    back = BaselineComparison.from_json(stored)
    assert back.scores[:-1] == c.scores[:-1] and back.scores[-1].mean == math.inf
    networks = {"Lagrangian network": {1.0: (1e-5, 1e-6), 5.0: (2e-2, 1e-3)},
                "black box": {1.0: (None, None), 5.0: (math.inf, math.inf)}}
    table = baseline_table(networks, back, caption="x")
    md = to_markdown(table)
    assert "| model | rollout error over 1 s | rollout error over 5 s |" in md
    names = [row[0] for row in table.rows]
    assert names == ["Lagrangian network", "black box", "no motion", "ARX (order 2)",
                     "linear 2nd order"]
    assert table.rows[1][1:] == ("diverged", "diverged")
    assert table.rows[3][1].endswith("(1 of 2 left the training range)")
    assert table.rows[4][2] == "diverged"
    lines = verdict_lines(networks, back)
    assert len(lines) == 2 and lines[0].startswith("- Lagrangian network: at 1 s beats")
    assert "at 5 s LOSES to no motion" in lines[0]
    assert lines[1].startswith("- black box: at 1 s LOSES")
