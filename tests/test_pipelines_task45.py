"""Paper tasks 4 and 5 end to end on quick settings, and their notebooks: the checks of
test_pipelines.py, in a module of their own so that the suite's two xdist workers (which take
whole modules) run these two long pipelines beside tasks 1-3."""

from __future__ import annotations

import pytest
from test_pipelines import NOTEBOOKS, check_quick_pipeline, run_notebook

pytestmark = pytest.mark.timeout(900)

HERE = ("task4", "task5")


@pytest.mark.parametrize("task", HERE)
def test_quick_pipeline_writes_report_tables_and_figures(task, quick_runs):
    check_quick_pipeline(task, quick_runs)


@pytest.mark.parametrize("path", [p for p in NOTEBOOKS if p.stem in HERE], ids=lambda p: p.stem)
def test_notebook_executes(path, quick_runs, monkeypatch):
    run_notebook(path, quick_runs, monkeypatch)
