"""The dependency rule of the design: symbolic never imports jax; learn never imports casadi or
sympy (checked in fresh interpreters, importing every module of the package)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules(package: str) -> list[str]:
    return [f"{package}.{p.stem}" for p in sorted((ROOT / package).glob("*.py"))
            if p.stem != "__init__"]


@pytest.mark.parametrize(
    ("package", "forbidden"), [("symbolic", ("jax", "equinox", "optax")),
                               ("learn", ("casadi", "sympy"))]
)
def test_package_does_not_import(package, forbidden):
    mods = [package, *_modules(package)]
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}: importlib.import_module(m)\n"
        f"bad = [f for f in {forbidden!r} if f in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == "", f"{package} imports {out.stdout.strip()}"
