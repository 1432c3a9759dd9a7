"""Generated C code for the equations of motion: export, compile, cache, load back.

This module holds the code cache; the derive output folder that ``softpinn derive`` writes is
:mod:`symbolic.codegen._generate`'s. The flow is

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

import hashlib
import json
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


#: caches whose stale build folders this process has removed (:func:`open_cache`)
_opened: set[Path] = set()


def open_cache(directory: str | os.PathLike | None = None) -> Path:
    """The cache directory (:func:`cache_dir`), its stale build folders and files (those of
    killed compiles, :func:`remove_stale_builds`) removed the first time this process opens
    it: a run served from the cache cleans up too, not only the next compile."""
    cache = cache_dir(directory)
    if cache not in _opened:
        _opened.add(cache)
        remove_stale_builds(cache)
    return cache


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
    check_names(fns)
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
    cache = open_cache(directory)
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


def check_names(fns: Mapping[str, ca.Function]) -> None:
    """Every function has a C name of its own (they share one C file)."""
    names = [f.name() for f in fns.values()]
    dupes = sorted({n for n in names if names.count(n) > 1})
    assert not dupes, f"two functions share the C name {dupes}"
