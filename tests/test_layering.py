"""The dependency rule of the design: symbolic never imports jax; learn never imports casadi or
sympy (checked in fresh interpreters, importing every module of the package)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules(package: str) -> list[str]:
    """Every module of one subpackage, nested folders included, by its installed name."""
    base = ROOT / package
    names = []
    for p in sorted(base.rglob("*.py")):
        parts = p.relative_to(base).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names.append(".".join(("softpinn", package, *parts)))
    return names


@pytest.mark.parametrize(
    ("package", "forbidden"), [("symbolic", ("jax", "equinox", "optax")),
                               ("learn", ("casadi", "sympy"))]
)
def test_package_does_not_import(package, forbidden):
    mods = _modules(package)
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}: importlib.import_module(m)\n"
        f"bad = [f for f in {forbidden!r} if f in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == "", f"{package} imports {out.stdout.strip()}"


def test_one_namespace_nothing_generic_top_level(tmp_path):
    """``softpinn.symbolic``, ``.learn`` and ``.bridge`` import from anywhere; the bare generic
    names (``symbolic``, ``learn``, ``bridge``) are not installed (run outside the repository,
    whose root would otherwise be on ``sys.path``)."""
    code = (
        "import importlib, softpinn, softpinn.symbolic, softpinn.learn, softpinn.bridge\n"
        "bad = []\n"
        "for name in ('symbolic', 'learn', 'bridge'):\n"
        "    try:\n"
        "        importlib.import_module(name)\n"
        "        bad.append(name)\n"
        "    except ImportError:\n"
        "        pass\n"
        "print(softpinn.__version__, ','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=tmp_path)
    version, bad = (out.stdout.strip().split(" ") + [""])[:2]
    assert version and version != "0+unknown"
    assert bad == "", f"generic top-level packages importable: {bad}"


def test_lazy_entry_points_resolve():
    """Every name ``import softpinn`` advertises resolves to a real object."""
    import softpinn

    for name in softpinn.__all__:
        assert getattr(softpinn, name) is not None, name


def _import_graph() -> dict[str, set[str]]:
    """Module -> the softpinn modules it imports (module-level and function-local alike), read
    from the source with ``ast``; ``from pkg import name`` counts as importing ``pkg.name`` when
    that is a module, else ``pkg`` itself."""
    import ast

    modules = {m: None for pkg in ("symbolic", "learn", "bridge") for m in _modules(pkg)}
    modules["softpinn"] = None
    graph: dict[str, set[str]] = {}
    for mod in modules:
        rel = mod.split(".")[1:]
        path = ROOT.joinpath(*rel)
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        is_pkg = path.name == "__init__.py"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    base = base[: len(base) - node.level + 1]
                    src = ".".join(base + ([node.module] if node.module else []))
                else:
                    src = node.module or ""
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in modules else src
                           for a in node.names]
            else:
                continue
            deps |= {t for t in targets if t in modules and t != mod}
        graph[mod] = deps
    return graph


def test_no_import_cycles():
    """No module reaches itself through imports, function-local ones included."""
    graph = _import_graph()
    assert len(graph) > 30
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_every_subpackage_is_installed():
    """Every folder of the three subpackages with an ``__init__.py`` is listed in pyproject's
    ``packages`` (the editable install finds unlisted ones; a wheel would silently lack them)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
                 ["packages"])
    tracked = subprocess.run(["git", "ls-files", "*__init__.py"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.split()  # work in progress aside
    found = {"softpinn"}
    for name in tracked:
        rel = Path(name).parent.parts
        if rel and rel[0] in ("symbolic", "learn", "bridge"):
            found.add(".".join(("softpinn", *rel)))
    assert found - listed == set(), f"not in pyproject packages: {sorted(found - listed)}"
    assert listed - found == set(), f"listed but missing: {sorted(listed - found)}"


def test_every_cli_flag_has_help_and_shows_its_default():
    """Each subcommand's options carry help text, and --help shows the defaults."""
    import argparse

    from softpinn.bridge.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {"train", "simulate", "reproduce", "export"} <= set(sub.choices)
    for name, command in sub.choices.items():
        missing = [a.option_strings or a.dest for a in command._actions
                   if not a.help and a.dest != "help"]
        assert missing == [], f"softpinn {name}: options without help: {missing}"
        assert issubclass(command.formatter_class, argparse.ArgumentDefaultsHelpFormatter)
    text = sub.choices["train"].format_help()
    assert "(default: 1000)" in text and "(default: None)" not in text
