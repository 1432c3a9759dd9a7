"""The documentation tells the truth: the README's Python block runs as written, every link
between the repository's documents resolves, no file links outside the repository, the spec
document lists every [data] key, and docs/equations.md points at files that exist."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "RESULTS.md", *sorted((ROOT / "docs").glob("*.md"))]


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, re.S)


@pytest.mark.timeout(600)
def test_readme_python_block_runs_as_written(tmp_path):
    (block,) = _python_blocks((ROOT / "README.md").read_text())
    out = subprocess.run([sys.executable, "-c", block], cwd=tmp_path, capture_output=True,
                         text=True, timeout=600, env={"MPLBACKEND": "Agg", "PATH": "/usr/bin",
                                                      "HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr[-3000:]
    assert (tmp_path / "runs" / "api" / "t1-lnn" / "model.eqx").is_file()


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_links_resolve_inside_the_repository(doc):
    text = doc.read_text()
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if re.match(r"[a-z]+://", target):
            continue
        path = (doc.parent / target).resolve()
        assert path.exists(), f"{doc.name}: broken link {target}"
        assert ROOT in path.parents or path == ROOT, f"{doc.name}: link leaves the repo {target}"


def test_no_file_points_outside_the_repository():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    outside = ("../" + "shared", "DESIGN" + ".md")  # spelled so that this file does not match
    bad = []
    for name in files:
        if not name.endswith((".py", ".md", ".toml", ".ipynb", ".json")):
            continue
        text = (ROOT / name).read_text(errors="replace")
        if any(word in text for word in outside):
            bad.append(name)
    assert bad == [], f"files that point outside the repository: {bad}"


def test_spec_doc_lists_every_data_key():
    from softpinn.symbolic.simulation._datasets import DATA_KEYS

    text = (ROOT / "docs" / "spec.md").read_text()
    missing = [k for k in DATA_KEYS if f"`{k}`" not in text]
    assert missing == [], f"docs/spec.md lacks [data] keys {missing}"


def test_recipe_doc_lists_every_recipe_key():
    from softpinn.symbolic.spec._recipe import (
        BUDGET_KEYS,
        LOSS_KEYS,
        NETWORK_KEYS,
        QUICK_KEYS,
        TOP_KEYS,
    )

    text = (ROOT / "docs" / "recipes.md").read_text()
    keys = {*TOP_KEYS, *BUDGET_KEYS, *LOSS_KEYS, *QUICK_KEYS,
            *(k for ks in NETWORK_KEYS.values() for k in ks)}
    missing = sorted(k for k in keys
                     if f"`{k}`" not in text and not re.search(rf"^{k} = ", text, re.M))
    assert missing == [], f"docs/recipes.md lacks recipe keys {missing}"


def test_equation_map_points_at_existing_files():
    text = (ROOT / "docs" / "equations.md").read_text()
    paths = re.findall(r"`((?:symbolic|learn|bridge)/[\w/]+\.py)`", text)
    assert len(paths) >= 15
    missing = [p for p in paths if not (ROOT / p).is_file()]
    assert missing == [], f"docs/equations.md names missing files {missing}"
    for eq in (4, 6, 7, 8, 9, 10, 13, 18, 23, 25, 26, 27):
        assert re.search(rf"\b{eq}\b", text), f"eq. {eq} missing from docs/equations.md"


def test_cli_doc_shows_every_command():
    import argparse

    from softpinn.bridge.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    text = (ROOT / "docs" / "cli.md").read_text()
    missing = [c for c in sub.choices if f"## softpinn {c}\n" not in text]
    assert missing == [], f"docs/cli.md lacks commands {missing}"


def test_rundir_doc_lists_every_setting_that_may_change_on_resume():
    from softpinn.learn._config import RESUMABLE

    text = (ROOT / "docs" / "rundir.md").read_text()
    missing = [f for f in RESUMABLE if f"`--{f.replace('_', '-')}`" not in text]
    assert not missing, f"docs/rundir.md does not list {missing} among the resumable settings"
