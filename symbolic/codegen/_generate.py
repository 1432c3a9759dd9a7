"""The derive output folder (``softpinn derive``): the functions' C source, shared library,
CasADi serialized functions and ``summary.json``, written as a whole (:func:`generate`) and read
back (:func:`read_derive_summary`); the library is also installed in the code cache of
:mod:`symbolic.codegen._codegen`, so that :func:`~symbolic.codegen._codegen.compile_functions` of
the same functions finds it.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import casadi as ca

from softpinn.errors import UserError
from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen._codegen import (
    CompilerWarning,
    _warned,  # warned once per process, shared with compile_functions
    check_names,
    content_hash,
    open_cache,
    remove_stale_builds,
    write_c,
)
from softpinn.symbolic.codegen._compiler import (
    DEFAULT_FLAGS,
    DEFAULT_TIMEOUT,
    compile_c,
    find_compiler,
)


def expression_sizes(fn: ca.Function) -> dict[str, int]:
    """Size of a function's expression graph: its own nodes and instructions (SX or MX), and
    for an MX graph the SX nodes/instructions of every SX function it calls (each counted once,
    a mapped body once): ``sx_nodes``, ``sx_instructions``, ``sx_functions``."""
    out = {"n_nodes": int(fn.n_nodes()), "n_instructions": int(fn.n_instructions())}
    if fn.is_a("SXFunction"):
        out.update(sx_nodes=out["n_nodes"], sx_instructions=out["n_instructions"], sx_functions=1)
        return out
    seen = {}
    try:
        deps = fn.find_functions()
    except RuntimeError:  # pragma: no cover - a function kind without dependency listing
        deps = []
    for g in deps:
        if g.is_a("SXFunction") and g.name() not in seen:
            seen[g.name()] = (int(g.n_nodes()), int(g.n_instructions()))
    out.update(
        sx_nodes=sum(v[0] for v in seen.values()),
        sx_instructions=sum(v[1] for v in seen.values()),
        sx_functions=len(seen),
    )
    return out


def generate(
    fns: Mapping[str, ca.Function],
    out_dir: str | os.PathLike,
    *,
    compiler: str | os.PathLike | None = None,
    flags: Sequence[str] = DEFAULT_FLAGS,
    timeout: float = DEFAULT_TIMEOUT,
    timings: Mapping[str, float] | None = None,
    extra: Mapping | None = None,
    cache: str | os.PathLike | None | bool = None,
    files: Mapping[str, str] | None = None,
) -> dict:
    """Write C source, shared library, CasADi serialized functions and ``summary.json``.

    ``out_dir`` receives ``<name>.casadi`` for every function (``Function.save``; load with
    ``casadi.Function.load``), ``softpinn_eom.c``, ``softpinn_eom.so`` (when a compiler is
    found) and ``summary.json`` with the expression sizes, the timings (``timings`` given by the
    caller, e.g. derive and function creation, plus C generation and compilation), the compiler
    and flags. Returns the summary. The library is also installed in the cache (``cache``: a
    directory, None for the default, False for no), so that :func:`compile_functions` of the same
    functions finds it; a cache that cannot be written is skipped with a warning. ``files``:
    further text files to write beside them (``{name: text}``, e.g. the functions as replayable
    programs), listed in the summary's ``files``.

    Everything is built in a temporary sibling folder (``.<name>.partial-<pid>@<host>``) and
    appears at ``out_dir`` only when complete: a new folder is renamed into place; into an
    existing one (an earlier output) the files are moved one by one, ``summary.json`` last, and
    files the earlier ``summary.json`` listed that this output has not are removed. Other files
    in the folder are left alone. An interrupted call leaves ``out_dir`` as it was; a sibling
    left by a killed run is removed by the next call.
    """
    check_names(fns)
    if not (timeout > 0 and math.isfinite(timeout)):
        raise UserError(f"timeout: expected a finite number of seconds > 0, got {timeout}")
    out = Path(out_dir).absolute()
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    work = outputs.partial_path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        outputs.remove_stale_partials(out)
        outputs.remove_path(work)
        work.mkdir()
    except OSError as exc:
        raise outputs.cannot_write("output folder", out, exc) from None
    try:
        summary = _generate_into(work, out, fns, compiler, tuple(flags), timeout, timings, extra,
                                 cache, files or {})
        _install_folder(work, out, summary)
    finally:
        outputs.remove_path(work)
    return summary


def _generate_into(work, out, fns, compiler, flags, timeout, timings, extra, cache,
                   files) -> dict:
    times = dict(timings or {})
    for key, fn in fns.items():
        fn.save(str(work / f"{key}.casadi"))
    for name, text in files.items():
        if not name or "/" in name or os.sep in name or name in (".", ".."):
            raise UserError(f"files: {name!r} is not a plain file name")
        (work / name).write_text(text, "utf-8")
    t0 = time.perf_counter()
    source = write_c(fns, work, "softpinn_eom")
    times["generate_c"] = time.perf_counter() - t0
    cc = find_compiler(compiler)
    library = None
    if cc is not None:
        library = work / "softpinn_eom.so"
        times["compile"] = compile_c(source, library, compiler=cc, flags=flags, timeout=timeout)
        if cache is not False:
            _install_in_cache(fns, library, source, cc, flags, cache)
    else:
        warnings.warn(
            f"no C compiler found (compiler setting: {compiler or 'default'}); "
            "wrote the C source but no shared library",
            CompilerWarning,
            stacklevel=3,
        )
    summary = {
        "directory": str(out),
        "source": source.name,
        "source_bytes": source.stat().st_size,
        "library": library.name if library else None,
        "compiler": cc,
        "flags": list(flags) if cc else [],
        "casadi": ca.__version__,
        "functions": {
            key: {
                "name": fn.name(),
                "inputs": list(fn.name_in()),
                "outputs": list(fn.name_out()),
                "file": f"{key}.casadi",
                "symbolic": "SX" if fn.is_a("SXFunction") else "MX",
                **expression_sizes(fn),
            }
            for key, fn in fns.items()
        },
        "timings_s": times,
    }
    if files:
        summary["files"] = sorted(files)
    if extra:
        summary.update(extra)
    (work / "summary.json").write_text(outputs.dumps(summary, what="summary.json", indent=1))
    return summary


def read_derive_summary(folder: str | os.PathLike) -> dict | None:
    """``folder``'s ``summary.json`` where it is one that :func:`generate` wrote (a JSON object
    with its ``source``, ``casadi`` and ``functions`` keys), else None: a file of that name that
    someone else wrote makes the folder no earlier derive output."""
    try:
        obj = json.loads((Path(folder) / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not (isinstance(obj, dict) and isinstance(obj.get("functions"), dict)
            and isinstance(obj.get("source"), str) and "casadi" in obj):
        return None
    return obj


def summary_files(summary: Mapping) -> set[str]:
    """The file names a derive ``summary.json`` says its folder holds."""
    names = {"summary.json", str(summary.get("source") or "")}
    if summary.get("library"):
        names.add(str(summary["library"]))
    for info in (summary.get("functions") or {}).values():
        if isinstance(info, Mapping) and info.get("file"):
            names.add(str(info["file"]))
    names.update(str(n) for n in summary.get("files") or () if isinstance(n, str))
    return {n for n in names if n and "/" not in n and os.sep not in n and n not in (".", "..")}


def _install_folder(work: Path, out: Path, summary: Mapping) -> None:
    """Move the finished folder ``work`` to ``out`` (see :func:`generate`)."""
    try:
        if not out.exists():
            try:
                os.rename(work, out)  # atomic; onto an empty folder made meanwhile, too
                return
            except OSError:
                if not out.is_dir():
                    raise
        previous = read_derive_summary(out)
        earlier = summary_files(previous) if previous is not None else set()
        names = sorted(p.name for p in work.iterdir() if p.name != "summary.json")
        for name in [*names, "summary.json"]:
            os.replace(work / name, out / name)
        for name in sorted(earlier - summary_files(summary)):
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                (out / name).unlink()
    except OSError as exc:
        raise outputs.cannot_write("output folder", out, exc) from None


def _install_in_cache(fns, library: Path, source: Path, cc: str, flags, directory) -> None:
    """Copy a compiled library and its source into the cache; a cache that cannot be written
    is skipped with one warning (the derive output itself is complete)."""
    key = content_hash(fns, cc, tuple(flags))
    cache = open_cache(None if directory is True else directory)
    root = cache / key
    target = root / f"softpinn_{key}.so"
    try:
        if target.is_file():
            return
        remove_stale_builds(cache)
        root.mkdir(parents=True, exist_ok=True)
        for src, dst in ((source, root / f"softpinn_{key}.c"), (library, target)):
            fd, tmp = tempfile.mkstemp(
                prefix=f".{dst.name}.partial-{outputs.owner_tag()}-", suffix="", dir=root
            )
            os.close(fd)
            try:
                shutil.copyfile(src, tmp)
                outputs.install_file(Path(tmp), dst, mode=0o777 if dst.suffix == ".so" else 0o666)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
    except OSError as exc:
        if f"cache {cache}" not in _warned:
            _warned.add(f"cache {cache}")
            warnings.warn(
                f"the compiled-code cache {cache} cannot be written "
                f"({exc.strerror or type(exc).__name__}); the library was not installed there",
                CompilerWarning,
                stacklevel=4,
            )
