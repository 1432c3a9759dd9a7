"""Generated C code for the equations of motion: export, compile, cache, load back.

This is the only module of :mod:`symbolic` that writes compiled artefacts. The flow is

``dict[str, casadi.Function]`` (SX/MX, from :func:`symbolic.model._functions.functions`)
-> one C file (``casadi.CodeGenerator``) -> ``gcc -O1 -fPIC -shared`` -> shared library
-> ``casadi.external`` (absolute path) -> ``dict[str, casadi.Function]`` with the same names,
inputs and outputs.

Compiled libraries are cached by a SHA-256 hash of every function's ``serialize()`` together
with the compiler, its flags and the CasADi version, in a cache directory (argument, else the
environment variable ``SOFTPINN_CACHE``, else ``~/.cache/softpinn``). A library is compiled to a
temporary file and installed with :func:`os.replace`, so a concurrent or interrupted compile never
leaves a broken file behind. The compiler runs in its own process group under a small supervisor:
at its timeout, on an interrupt (Ctrl-C) or any other error the whole group is killed (``cc1``
survives a plain kill), and when this process dies without a chance to clean up (SIGKILL,
SIGTERM) the supervisor is told by the kernel (``PR_SET_PDEATHSIG``) and kills the group itself,
so no compiler outlives the command. Temporary build folders carry their writer's
``<pid>@<host>``; one whose process is gone (a killed run) is removed by the next compile.
If no C compiler is found, or the cache cannot be written, :func:`compiled` falls back to
CasADi's SX/MX virtual machine and warns once (per setting and process).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca

from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen._compiler import (
    DEFAULT_FLAGS,
    DEFAULT_TIMEOUT,
    CompilerError,
    compile_c,
    find_compiler,
)
from softpinn.errors import UserError

_warned: set[str] = set()


class CompilerWarning(UserWarning):
    """No C compiler: the functions run in CasADi's virtual machine (slower, same results)."""


def cache_dir(directory: str | os.PathLike | None = None) -> Path:
    """The cache directory: ``directory``, else ``$SOFTPINN_CACHE``, else ``~/.cache/softpinn``."""
    if directory is not None:
        return Path(directory).expanduser().absolute()
    env = os.environ.get("SOFTPINN_CACHE")
    if env:
        return Path(env).expanduser().absolute()
    return Path("~/.cache/softpinn").expanduser().absolute()


def content_hash(
    fns: Mapping[str, ca.Function], compiler: str = "", flags: Sequence[str] = ()
) -> str:
    """SHA-256 (hex, 24 characters) of the functions' serialized form, compiler and flags."""
    h = hashlib.sha256()
    h.update(f"casadi {ca.__version__}\0compiler {compiler}\0flags {' '.join(flags)}\0".encode())
    for key in sorted(fns):
        h.update(f"{key}\0{fns[key].name()}\0".encode())
        h.update(fns[key].serialize().encode())
    return h.hexdigest()[:24]


def write_c(fns: Mapping[str, ca.Function], directory: Path, stem: str) -> Path:
    """Write one C file holding every function (named as ``fn.name()``); return its path.

    ``Function.generate``/``CodeGenerator.generate`` reject a file name with a directory, so the
    directory is passed as the prefix.
    """
    _check_names(fns)
    directory.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator(f"{stem}.c", {"with_header": False, "casadi_real": "double"})
    for key in sorted(fns):
        cg.add(fns[key])
    return Path(cg.generate(str(directory) + os.sep))


def load_external(
    fns: Mapping[str, ca.Function], library: Path, *, enable_fd: bool = True
) -> dict[str, ca.Function]:
    """Load every function back from ``library`` with ``casadi.external`` (absolute path).

    ``enable_fd`` lets CasADi differentiate a loaded function by finite differences (the
    integrator's Jacobian; docs/pitfalls.md: an exact Jacobian as C is too big to compile).
    """
    path = str(Path(library).absolute())
    opts = {"enable_fd": True} if enable_fd else {}
    out = {key: ca.external(fn.name(), path, opts) for key, fn in fns.items()}
    for key, fn in fns.items():
        _SOURCES[id(out[key])] = (out[key], fn)  # holding the loaded one keeps its id unique
    return out


#: id(loaded external) -> (the loaded Function, the SX/MX Function it was compiled from)
_SOURCES: dict[int, tuple[ca.Function, ca.Function]] = {}


def source_of(fn: ca.Function) -> ca.Function:
    """The SX/MX Function a compiled one (from :func:`load_external`) was made from; ``fn``
    itself when it is not a loaded library function (for :mod:`.kernel`, which needs the
    instructions)."""
    entry = _SOURCES.get(id(fn))
    return entry[1] if entry is not None and entry[0] is fn else fn


@dataclass
class Compiled:
    """What :func:`compile_functions` returns.

    ``functions`` has the same keys, names, inputs and outputs as the input dict. ``compiled``
    is False when they fell back to the virtual machine; ``from_cache`` is True when the library
    was found in the cache and nothing was compiled.
    """

    functions: dict[str, ca.Function]
    compiled: bool
    from_cache: bool
    library: Path | None = None
    source: Path | None = None
    key: str = ""
    compile_seconds: float = 0.0
    generate_seconds: float = 0.0
    compiler: str | None = None
    flags: tuple[str, ...] = ()
    info: dict = field(default_factory=dict)


def compile_functions(
    fns: Mapping[str, ca.Function],
    *,
    directory: str | os.PathLike | None = None,
    compiler: str | os.PathLike | None = None,
    flags: Sequence[str] = DEFAULT_FLAGS,
    timeout: float = DEFAULT_TIMEOUT,
    enable_fd: bool = True,
    fallback: bool = True,
) -> Compiled:
    """Compile ``fns`` to C (cached) and load them back; fall back to the VM without a compiler.

    The library lives at ``<cache>/<hash>/softpinn_<hash>.so`` next to its C source. A second
    call with the same functions, compiler and flags loads it without compiling
    (``from_cache=True``).
    """
    flags = tuple(flags)
    cc = find_compiler(compiler)
    if cc is None:
        setting = str(compiler) if compiler is not None else "default"
        if not fallback:
            raise CompilerError(f"no C compiler found (compiler setting: {setting})")
        if setting not in _warned:
            _warned.add(setting)
            warnings.warn(
                f"no C compiler found (compiler setting: {setting}); the equations of motion run "
                "in CasADi's virtual machine, which is slower",
                CompilerWarning,
                stacklevel=2,
            )
        return Compiled(functions=dict(fns), compiled=False, from_cache=False)
    key = content_hash(fns, cc, flags)
    cache = cache_dir(directory)
    root = cache / key
    stem = f"softpinn_{key}"
    library = root / f"{stem}.so"
    source = root / f"{stem}.c"
    gen_s = comp_s = 0.0
    from_cache = library.is_file()
    if not from_cache:
        remove_stale_builds(cache)
        try:
            # a private build directory: concurrent processes never read a half-written file
            root.mkdir(parents=True, exist_ok=True)
            build = Path(tempfile.mkdtemp(prefix=f".build-{outputs.owner_tag()}-", dir=root))
        except OSError as exc:
            message = (
                f"the compiled-code cache {cache} cannot be written "
                f"({exc.strerror or type(exc).__name__}; set SOFTPINN_CACHE to a writable folder)"
            )
            if not fallback:
                raise CompilerError(message) from None
            if f"cache {cache}" not in _warned:
                _warned.add(f"cache {cache}")
                warnings.warn(
                    f"{message}; the equations of motion run in CasADi's virtual machine, "
                    "which is slower",
                    CompilerWarning,
                    stacklevel=2,
                )
            return Compiled(functions=dict(fns), compiled=False, from_cache=False)
        try:
            t0 = time.perf_counter()
            tmp_source = write_c(fns, build, stem)
            gen_s = time.perf_counter() - t0
            comp_s = compile_c(
                tmp_source, build / library.name, compiler=cc, flags=flags, timeout=timeout
            )
            info = {
                "functions": {k: f.name() for k, f in fns.items()},
                "compiler": cc,
                "flags": list(flags),
                "casadi": ca.__version__,
            }
            (build / "functions.json").write_text(json.dumps(info, indent=1))
            os.replace(build / "functions.json", root / "functions.json")
            os.replace(tmp_source, source)
            os.replace(build / library.name, library)  # last: its presence means "cached"
        finally:
            shutil.rmtree(build, ignore_errors=True)
    loaded = load_external(fns, library, enable_fd=enable_fd)
    return Compiled(
        functions=loaded,
        compiled=True,
        from_cache=from_cache,
        library=library,
        source=source,
        key=key,
        compile_seconds=comp_s,
        generate_seconds=gen_s,
        compiler=cc,
        flags=flags,
    )


def remove_stale_builds(cache: Path) -> list[Path]:
    """Remove the temporary build folders and files a killed compile left in the cache
    (``.build-<pid>@<host>-*``, ``.<file>.partial-<pid>@<host>-*``): those whose process is gone
    (this host), else older than a day; untagged ones (older versions) after an hour."""
    removed = []
    try:
        entries = list(cache.glob("*/.*"))
    except OSError:
        return removed
    for entry in entries:
        name = entry.name
        if name.startswith(".build-"):
            tag = name[len(".build-"):].rpartition("-")[0]
        elif ".partial-" in name:
            tag = name.partition(".partial-")[2].rpartition("-")[0]
        else:
            continue
        if outputs.is_stale(entry, tag):
            outputs.remove_path(entry)
            removed.append(entry)
    return removed


def compiled(fns: Mapping[str, ca.Function], **kwargs) -> dict[str, ca.Function]:
    """The functions compiled to C and loaded back (or, without a compiler, unchanged).

    Keyword arguments are those of :func:`compile_functions`.
    """
    return compile_functions(fns, **kwargs).functions


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
    _check_names(fns)
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
    cache = cache_dir(None if directory is True else directory)
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


def _check_names(fns: Mapping[str, ca.Function]) -> None:
    names = [f.name() for f in fns.values()]
    dupes = sorted({n for n in names if names.count(n) > 1})
    assert not dupes, f"two functions share the C name {dupes}"
