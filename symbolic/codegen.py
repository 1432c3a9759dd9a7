"""Generated C code for the equations of motion: export, compile, cache, load back.

This is the only module of :mod:`symbolic` that writes compiled artefacts. The flow is

``dict[str, casadi.Function]`` (SX/MX, from :func:`symbolic.functions.functions`)
-> one C file (``casadi.CodeGenerator``) -> ``gcc -O1 -fPIC -shared`` -> shared library
-> ``casadi.external`` (absolute path) -> ``dict[str, casadi.Function]`` with the same names,
inputs and outputs.

Compiled libraries are cached by a SHA-256 hash of every function's ``serialize()`` together
with the compiler, its flags and the CasADi version, in a cache directory (argument, else the
environment variable ``SOFTPINN_CACHE``, else ``~/.cache/softpinn``). A library is compiled to a
temporary file and installed with :func:`os.replace`, so a concurrent or interrupted compile never
leaves a broken file behind. A compiler that runs past its timeout is killed with its whole process
group (``cc1`` survives a plain kill). If no C compiler is found, :func:`compiled` falls back to
CasADi's SX/MX virtual machine and warns once (per compiler setting and process).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca

from .errors import UserError

#: Compiler flags: -O1 compiles 1.5-6x faster than -O2 and runs as fast (docs/pitfalls.md).
DEFAULT_FLAGS: tuple[str, ...] = ("-O1", "-fPIC", "-shared")
DEFAULT_TIMEOUT = 600.0

_warned: set[str] = set()


class CompilerError(UserError):
    """The C compiler failed or ran past its timeout."""


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


def find_compiler(compiler: str | os.PathLike | None = None) -> str | None:
    """Absolute path of the C compiler, or None if there is none.

    ``compiler`` (a name or a path) wins; else ``$CC``; else ``gcc``, then ``cc``.
    """
    candidates = [str(compiler)] if compiler is not None else []
    if compiler is None:
        if os.environ.get("CC"):
            candidates.append(os.environ["CC"])
        candidates += ["gcc", "cc"]
    for c in candidates:
        found = shutil.which(c)
        if found:
            return str(Path(found).absolute())
    return None


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


def compile_c(
    source: Path,
    library: Path,
    *,
    compiler: str,
    flags: Sequence[str] = DEFAULT_FLAGS,
    timeout: float = DEFAULT_TIMEOUT,
) -> float:
    """Compile ``source`` into the shared library ``library`` atomically; return the seconds taken.

    The output goes to a temporary file in the same directory, installed with ``os.replace``.
    On timeout the compiler's whole process group is killed.
    """
    library.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{library.stem}-", suffix=".so.tmp", dir=library.parent)
    os.close(fd)
    cmd = [compiler, *flags, str(source), "-o", tmp, "-lm"]
    start = time.perf_counter()
    try:
        with subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
        ) as proc:
            try:
                _, err = proc.communicate(timeout=timeout)
            except subprocess.TimeoutExpired:
                _kill_group(proc)
                raise CompilerError(
                    f"C compiler {compiler} ran past its timeout of {timeout:g} s on {source}; "
                    "raise the timeout or use fewer quadrature nodes"
                ) from None
        if proc.returncode != 0:
            last = err.decode(errors="replace").strip().splitlines()[-1:] or ["(no output)"]
            raise CompilerError(
                f"C compiler {compiler} failed on {source} (exit {proc.returncode}): {last[0]}"
            )
        os.chmod(tmp, 0o777 & ~_umask())
        os.replace(tmp, library)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return time.perf_counter() - start


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill the compiler's whole process group (its children, such as cc1, too)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.communicate()


def load_external(
    fns: Mapping[str, ca.Function], library: Path, *, enable_fd: bool = True
) -> dict[str, ca.Function]:
    """Load every function back from ``library`` with ``casadi.external`` (absolute path).

    ``enable_fd`` lets CasADi differentiate a loaded function by finite differences (the
    integrator's Jacobian; docs/pitfalls.md: an exact Jacobian as C is too big to compile).
    """
    path = str(Path(library).absolute())
    opts = {"enable_fd": True} if enable_fd else {}
    return {key: ca.external(fn.name(), path, opts) for key, fn in fns.items()}


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
    root = cache_dir(directory) / key
    stem = f"softpinn_{key}"
    library = root / f"{stem}.so"
    source = root / f"{stem}.c"
    gen_s = comp_s = 0.0
    from_cache = library.is_file()
    if not from_cache:
        # a private build directory: concurrent processes never read a half-written file
        root.mkdir(parents=True, exist_ok=True)
        build = Path(tempfile.mkdtemp(prefix=".build-", dir=root))
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
) -> dict:
    """Write C source, shared library, CasADi serialized functions and ``summary.json``.

    ``out_dir`` receives ``<name>.casadi`` for every function (``Function.save``; load with
    ``casadi.Function.load``), ``softpinn_eom.c``, ``softpinn_eom.so`` (when a compiler is
    found) and ``summary.json`` with the expression sizes, the timings (``timings`` given by the
    caller, e.g. derive and function creation, plus C generation and compilation), the compiler
    and flags. Returns the summary. The library is also installed in the cache (``cache``: a
    directory, None for the default, False for no), so that :func:`compile_functions` of the same
    functions finds it.
    """
    _check_names(fns)
    out = Path(out_dir).absolute()
    out.mkdir(parents=True, exist_ok=True)
    times = dict(timings or {})
    for key, fn in fns.items():
        fn.save(str(out / f"{key}.casadi"))
    t0 = time.perf_counter()
    source = write_c(fns, out, "softpinn_eom")
    times["generate_c"] = time.perf_counter() - t0
    cc = find_compiler(compiler)
    library = None
    if cc is not None:
        library = out / "softpinn_eom.so"
        times["compile"] = compile_c(source, library, compiler=cc, flags=flags, timeout=timeout)
        if cache is not False:
            _install_in_cache(fns, library, source, cc, flags, cache)
    else:
        warnings.warn(
            f"no C compiler found (compiler setting: {compiler or 'default'}); "
            "wrote the C source but no shared library",
            CompilerWarning,
            stacklevel=2,
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
    if extra:
        summary.update(extra)
    tmp = out / ".summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, out / "summary.json")
    return summary


def _install_in_cache(fns, library: Path, source: Path, cc: str, flags, directory) -> None:
    key = content_hash(fns, cc, tuple(flags))
    root = cache_dir(None if directory is True else directory) / key
    target = root / f"softpinn_{key}.so"
    if target.is_file():
        return
    root.mkdir(parents=True, exist_ok=True)
    for src, dst in ((source, root / f"softpinn_{key}.c"), (library, target)):
        fd, tmp = tempfile.mkstemp(prefix=f".{dst.stem}-", suffix=".tmp", dir=root)
        os.close(fd)
        try:
            shutil.copyfile(src, tmp)
            os.chmod(tmp, 0o777 & ~_umask() if dst.suffix == ".so" else 0o666 & ~_umask())
            os.replace(tmp, dst)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)


def _check_names(fns: Mapping[str, ca.Function]) -> None:
    names = [f.name() for f in fns.values()]
    dupes = sorted({n for n in names if names.count(n) > 1})
    assert not dupes, f"two functions share the C name {dupes}"
