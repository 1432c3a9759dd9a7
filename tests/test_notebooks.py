"""Every task notebook executes (quick settings), reusing the pipeline tests' runs."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from conftest import QUICK_EPOCHS
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("task*.ipynb"))
CONTROL = Path(__file__).parent.parent / "notebooks" / "control.ipynb"

pytestmark = pytest.mark.timeout(900)


def test_one_notebook_per_task():
    assert [p.stem for p in NOTEBOOKS] == ["task1", "task2", "task3", "task4", "task5"]


@pytest.mark.parametrize("path", [*NOTEBOOKS, CONTROL], ids=lambda p: p.stem)
def test_notebook_executes(path, quick_runs, monkeypatch):
    # the notebook then finds every stage done and only reports (control: task3's runs)
    quick_runs("task3" if path == CONTROL else path.stem)
    monkeypatch.setenv("SOFTPINN_OUT", str(quick_runs.root))
    monkeypatch.setenv("SOFTPINN_QUICK", "1")
    monkeypatch.setenv("SOFTPINN_EPOCHS", str(QUICK_EPOCHS))
    monkeypatch.setenv("SOFTPINN_LBFGS", "0")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 3
