"""The architecture's rules (``docs/architecture.md``), read from the source with ``ast``:

- the layers inside ``bridge`` and ``symbolic`` import only downwards, counting imports inside
  functions; so no cycle between subpackages;
- an import across subpackages inside a function only defers a heavy or optional dependency, and
  says so in a comment;
- ``bridge`` reaches ``learn`` and ``symbolic`` only through their faces (``softpinn.learn``,
  ``softpinn.symbolic``) or their few public modules, never a private ``_module``;
- a face's ``__all__`` lists every name it imports, and every name resolves;
- one class of each kind of error; no module over 450 lines; ``__init__`` files re-export.
"""

from __future__ import annotations

import ast
import importlib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("symbolic", "learn", "bridge")

#: bottom to top; a subpackage imports only those before it (same rank: neither imports the other)
LAYERS = {
    "bridge": [("base",), ("exact",), ("analysis",), ("figures",), ("export",), ("control",),
               ("tasks",), ("challenges", "sweep", "cosserat"), ("report",), ("app",), ("cli",)],
    "symbolic": [("spec",), ("derivation",), ("codegen",), ("model",), ("simulation",),
                 ("recorded",), ("standin",), ("presets",)],
}
#: modules of learn and symbolic that bridge may import besides the faces (docs/architecture.md)
PUBLIC_MODULES = {"softpinn.learn.plots", "softpinn.learn.jitcache", "softpinn.learn.xlaflags",
                  "softpinn.learn.distributed"}
MAX_LINES = 450
MAX_INIT_LOGIC = 60
MAX_DEFERRED = 40


@dataclass(frozen=True)
class Import:
    src: str  # the importing module
    dst: str  # the softpinn module imported (``from pkg import name``: pkg.name if a module)
    in_function: bool
    path: Path
    line: int


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(("softpinn", *parts))


def _files() -> dict[str, Path]:
    files = {_module_name(p): p for p in sorted(ROOT.glob("*.py"))}
    files["softpinn"] = files.pop("softpinn.__init__", ROOT / "__init__.py")
    files.pop("softpinn.setup", None)
    for pkg in PACKAGES:
        files.update({_module_name(p): p for p in sorted((ROOT / pkg).rglob("*.py"))})
    return files


def _imports() -> list[Import]:
    files = _files()
    found = []
    for mod, path in files.items():
        tree = ast.parse(path.read_text("utf-8"))
        inside = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                inside |= {id(c) for c in ast.walk(node) if c is not node}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path}:{node.lineno}: relative import"
                src = node.module or ""
                targets = [f"{src}.{a.name}" if f"{src}.{a.name}" in files else src
                           for a in node.names]
            else:
                continue
            for t in targets:
                if t in files and t != mod:
                    found.append(Import(mod, t, id(node) in inside, path, node.lineno))
    return found


def _place(mod: str) -> tuple[str, str] | None:
    """(package, subpackage) of a module inside a layered package, else None."""
    parts = mod.split(".")
    if len(parts) >= 3 and parts[1] in LAYERS:
        return parts[1], parts[2]
    return None


def _rank(package: str, sub: str) -> int:
    for i, names in enumerate(LAYERS[package]):
        if sub in names:
            return i
    raise AssertionError(f"softpinn.{package}.{sub}: a subpackage with no layer; add it to "
                         "LAYERS here and to docs/architecture.md")


def test_layers_import_only_downwards():
    bad = []
    for imp in _imports():
        a, b = _place(imp.src), _place(imp.dst)
        if a is None or b is None or a[0] != b[0] or a[1] == b[1]:
            continue
        if a[1].endswith(".py") or b[1].endswith(".py"):
            continue
        files_a = (ROOT / a[0] / a[1]).is_dir()
        files_b = (ROOT / a[0] / b[1]).is_dir()
        if not (files_a and files_b):  # a module beside the subpackages: the package's bottom
            if files_a and not files_b:
                continue
            bad.append(f"{imp.path.relative_to(ROOT)}:{imp.line}: {imp.src} -> {imp.dst}")
            continue
        if _rank(a[0], b[1]) >= _rank(a[0], a[1]):
            bad.append(f"{imp.path.relative_to(ROOT)}:{imp.line}: {imp.src} -> {imp.dst}")
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_lower_packages_never_import_upwards():
    """softpinn.errors and the other root modules are leaves; symbolic and learn never import
    bridge; neither imports the other."""
    bad = []
    for imp in _imports():
        s, d = imp.src.split("."), imp.dst.split(".")
        s_pkg = s[1] if len(s) > 1 and s[1] in PACKAGES else "root"
        d_pkg = d[1] if len(d) > 1 and d[1] in PACKAGES else "root"
        if imp.src == "softpinn":
            continue  # the lazy entry points name everything
        if s_pkg == "root" and d_pkg != "root":
            bad.append(f"{imp.src} -> {imp.dst}")
        if s_pkg in ("symbolic", "learn") and d_pkg not in (s_pkg, "root"):
            bad.append(f"{imp.src} -> {imp.dst}")
    assert not bad, "\n".join(bad)


def _commented(imp: Import) -> bool:
    lines = imp.path.read_text("utf-8").splitlines()
    here = lines[imp.line - 1]
    above = lines[imp.line - 2] if imp.line >= 2 else ""
    return "#" in here or above.strip().startswith("#")


def _crosses(imp: Import) -> bool:
    s, d = imp.src.split("."), imp.dst.split(".")
    return s[:3] != d[:3]


def test_imports_inside_functions_only_defer_and_say_why():
    deferred = [i for i in _imports() if i.in_function and _crosses(i)]
    silent = [f"{i.path.relative_to(ROOT)}:{i.line}: {i.dst}" for i in deferred
              if not _commented(i)]
    assert not silent, ("imports inside functions without a comment saying what they defer:\n"
                        + "\n".join(silent))
    assert len(deferred) < MAX_DEFERRED, "\n".join(
        f"{i.path.relative_to(ROOT)}:{i.line}: {i.dst}" for i in deferred)


def test_bridge_reaches_learn_and_symbolic_through_their_faces():
    bad = []
    for imp in _imports():
        if not imp.src.startswith("softpinn.bridge"):
            continue
        d = imp.dst.split(".")
        if len(d) > 2 and d[1] in ("learn", "symbolic") and imp.dst not in PUBLIC_MODULES:
            bad.append(f"{imp.path.relative_to(ROOT)}:{imp.line}: {imp.dst}")
    assert not bad, "bridge imports behind a face:\n" + "\n".join(bad)


def test_internal_modules_are_private():
    """Inside learn and symbolic every module is ``_private`` or a documented public one."""
    bad = []
    for mod in _files():
        parts = mod.split(".")
        if len(parts) > 2 and parts[1] in ("learn", "symbolic") and mod not in PUBLIC_MODULES:
            leaf = parts[-1]
            is_pkg = (ROOT.joinpath(*parts[1:]) / "__init__.py").exists()
            if not is_pkg and not leaf.startswith("_"):
                bad.append(mod)
    assert not bad, bad


@pytest.mark.parametrize("face", ["softpinn.learn", "softpinn.symbolic", "softpinn.bridge"])
def test_faces_list_what_they_export(face):
    module = importlib.import_module(face)
    path = ROOT.joinpath(*face.split(".")[1:]) / "__init__.py"
    tree = ast.parse(path.read_text("utf-8"))
    imported = {a.asname or a.name for n in tree.body if isinstance(n, ast.ImportFrom)
                for a in n.names if n.module != "__future__"}
    assert set(module.__all__) >= imported - {"annotations", "importlib"}
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{face}.{name}"


def test_one_class_of_each_error():
    defined: dict[str, list[str]] = {}
    for mod, path in _files().items():
        for node in ast.walk(ast.parse(path.read_text("utf-8"))):
            if isinstance(node, ast.ClassDef):
                defined.setdefault(node.name, []).append(mod)
    for name in ("UserError", "TrainingDiverged"):
        assert len(defined.get(name, [])) == 1, f"{name} defined in {defined.get(name)}"


def test_modules_are_small_and_inits_only_re_export():
    long, busy = [], []
    for path in _files().values():
        lines = path.read_text("utf-8").splitlines()
        if len(lines) > MAX_LINES:
            long.append(f"{path.relative_to(ROOT)}: {len(lines)} lines")
        if path.name == "__init__.py":
            tree = ast.parse("\n".join(lines))
            logic = 0
            for node in tree.body:
                if isinstance(node, ast.Import | ast.ImportFrom):
                    continue
                if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
                    continue  # the docstring
                if isinstance(node, ast.Assign | ast.AnnAssign) and any(
                        isinstance(t, ast.Name) and t.id in ("__all__", "_LAZY")
                        for t in getattr(node, "targets", [getattr(node, "target", None)])):
                    continue
                logic += node.end_lineno - node.lineno + 1
            if logic > MAX_INIT_LOGIC:
                busy.append(f"{path.relative_to(ROOT)}: {logic} lines of logic")
    assert not long, "modules over the limit:\n" + "\n".join(long)
    assert not busy, "__init__ files with logic:\n" + "\n".join(busy)
