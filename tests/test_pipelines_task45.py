"""Paper tasks 4 and 5 end to end on quick settings, and their notebooks: the checks of
test_pipelines.py, in a module of their own so that the suite's two xdist workers (which take
whole modules) run these two long pipelines beside tasks 1-3."""

from __future__ import annotations

import pytest
from test_pipelines import NOTEBOOKS, check_quick_pipeline, run_notebook

from softpinn.symbolic.spec._spec import load_spec

pytestmark = pytest.mark.timeout(900)

HERE = ("task4", "task5")


@pytest.mark.parametrize("task", HERE)
def test_quick_pipeline_writes_report_tables_and_figures(task, quick_runs):
    check_quick_pipeline(task, quick_runs)


@pytest.mark.parametrize("path", [p for p in NOTEBOOKS if p.stem in HERE], ids=lambda p: p.stem)
def test_notebook_executes(path, quick_runs, monkeypatch):
    run_notebook(path, quick_runs, monkeypatch)


def test_a_report_draws_its_variants_figures_in_processes(quick_runs, tmp_path):
    """With --jobs 2 a report draws its variants' figures in two processes: the same files
    (drafts, as the quick run's), pixel for pixel, and the same report lines as the quick run's
    own (drawn in one)."""
    import os

    from softpinn.bridge.figures.figsave import draft_figures
    from softpinn.bridge.report.task import _all_variant_figures

    result = quick_runs("task5")
    out, own = result.out_dir, result.out_dir / "figures"
    fig_dir = tmp_path / "figures"
    fig_dir.mkdir()
    with draft_figures():
        lines = _all_variant_figures(load_spec("task5"), result.plan, result.results, fig_dir,
                                     out, jobs=2)
    assert list(lines) == list(result.results["variants"])  # every variant, in order
    drawn = {p.name for p in fig_dir.iterdir()}
    assert drawn and drawn <= {p.name for p in own.iterdir()}
    assert not any(name.endswith(".pdf") for name in drawn)
    for name in sorted(drawn):
        if name.endswith(".png"):
            assert (fig_dir / name).read_bytes() == (own / name).read_bytes(), name
    report = result.report.read_text()
    for vname, own_lines in lines.items():
        text = "\n".join(own_lines).replace(os.path.relpath(fig_dir, out), "figures")
        assert text and text in report, vname
