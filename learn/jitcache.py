"""XLA's compiled programs kept on disk and shared by every softpinn process on a machine.

Every training, prediction and analysis compiles its programs with XLA first: a structured
Lagrangian network's training epoch takes 5-10 s to compile on a 2-core machine, as long as
several epochs. Processes that compile the same program (task 5's three Lagrangian networks, one
per rate, in ``reproduce``'s worker processes; a second ``softpinn train`` on other data of the
same shapes; a rerun; the test suite's processes) load it from JAX's persistent compilation
cache instead, bit for bit the same program (a cache key is a hash of the program, XLA's flags,
the device and jaxlib's version).

Where: ``$SOFTPINN_JIT_CACHE``, else ``jax/`` in softpinn's code cache (``$SOFTPINN_CACHE``,
else ``~/.cache/softpinn``), in a folder per machine: its name hashes the CPU's model and
feature flags and jaxlib's build, because XLA compiles for the host CPU and a program built on
one machine may not run on another (a home folder shared by a cluster's nodes). The cache keeps
at most :data:`MAX_BYTES`, evicting the programs used least recently (JAX's LRU cache, which
locks with ``filelock``). ``SOFTPINN_JIT_CACHE=off`` turns it off; a ``JAX_COMPILATION_CACHE_DIR``
the user set is left as it is. A folder's programs are found only in that folder: JAX's cache
keys include the folder's path (XLA's GPU autotuning cache lives inside it), so a copy of the
folder elsewhere starts empty.

Some CPUs reject every program XLA has cached on them (jax-ml/jax#38445: XLA's loader takes two
LLVM tuning hints recorded at compile time, ``+prefer-no-gather/scatter``, for missing CPU
features, logs an error per program and recompiles). Before a machine's folder is first used,
:func:`probe` compiles a tiny program in one subprocess and loads it in another; the folder is
used only if that load succeeded silently, and the answer is kept in ``probe.json`` beside it.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
from collections.abc import MutableMapping
from pathlib import Path

__all__ = ["MAX_BYTES", "cache_folder", "enable_compile_cache", "probe"]

#: the environment variable naming the folder, or "off"
ENV = "SOFTPINN_JIT_CACHE"
#: most bytes the cache keeps (least recently used programs are evicted beyond it)
MAX_BYTES = 2 * 1024**3
_OFF = {"0", "off", "no", "false", "none", ""}


def _machine_key() -> str:
    """A short hash of what a compiled program depends on outside its cache key: the CPU's
    model and feature flags, and the jaxlib build (its version and its libraries' sizes: the
    same wheel in two environments shares a folder)."""
    parts = [platform.system(), platform.machine()]
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags", "Features"))]
        parts += sorted(set(lines))
    except OSError:
        parts.append(platform.processor())
    try:  # jaxlib deferred: this module is read before JAX is imported (it configures JAX)
        import jaxlib
        import jaxlib.version

        parts.append(jaxlib.version.__version__)
        for lib in sorted(Path(jaxlib.__file__).parent.glob("*jax*.so")):
            st = lib.stat()
            parts.append(f"{lib.name}:{st.st_size}")
    except (ImportError, OSError):
        parts.append("no-jaxlib")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def cache_folder(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """This machine's cache folder, or None when ``SOFTPINN_JIT_CACHE`` turns the cache off."""
    env = os.environ if environ is None else environ
    given = env.get(ENV)
    if given is not None and given.strip().lower() in _OFF:
        return None
    if given:
        base = Path(given).expanduser()
    else:
        code = env.get("SOFTPINN_CACHE")
        base = (Path(code).expanduser() if code else Path.home() / ".cache" / "softpinn") / "jax"
    return base / _machine_key()


_PROBE = r"""
import sys
import jax
import jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
jax.jit(lambda x: jnp.sin(x) * 2.0 + x)(jnp.arange(3.0)).block_until_ready()
print(int("/jax/compilation_cache/cache_hits" in events))
"""


def probe(folder: Path, timeout: float = 60.0) -> bool:
    """Whether programs XLA caches in ``folder`` load again on this machine: a tiny program
    compiled and cached by one subprocess and loaded by a second, which must find it and log
    nothing about it. The answer is kept in ``folder/probe.json`` and read from there
    afterwards; a probe that could not run (it failed, or took over ``timeout`` seconds)
    answers False and keeps nothing, so the next process asks again."""
    record = folder / "probe.json"
    try:
        return bool(json.loads(record.read_text())["ok"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    where = folder / f"probe-{os.getpid()}"  # a folder of its own: processes may probe at once
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    ok, why = True, "a cached program loaded again"
    for attempt in ("write", "load"):
        try:
            run = subprocess.run([sys.executable, "-c", _PROBE, str(where)], env=env,
                                 capture_output=True, text=True, timeout=timeout)
        except (OSError, subprocess.TimeoutExpired):
            run = None
        if run is None or run.returncode != 0:
            shutil.rmtree(where, ignore_errors=True)
            return False  # the probe could not run (a loaded machine?): no cache now, ask again
        if attempt == "load" and (run.stdout.strip() != "1" or "AOT" in run.stderr):
            ok, why = False, f"XLA did not load its cached program: {run.stderr.strip()[-300:]}"
    shutil.rmtree(where, ignore_errors=True)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = record.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"ok": ok, "why": why}) + "\n")
        tmp.replace(record)
    except OSError:
        pass
    return ok


def enable_compile_cache(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """Turn on the persistent cache of compiled programs for this process and the processes it
    starts (through ``environ``, default this process's environment, which JAX reads when it
    is imported; JAX's settings too when it already is). Returns the folder in use, or None
    (turned off, a folder that cannot be written, a machine whose XLA rejects its own cached
    programs). A folder already given to JAX (``JAX_COMPILATION_CACHE_DIR``, or
    ``jax.config.update`` in this process) is kept and returned."""
    env = os.environ if environ is None else environ
    if env.get("JAX_COMPILATION_CACHE_DIR"):
        return Path(env["JAX_COMPILATION_CACHE_DIR"])
    if environ is None and "jax" in sys.modules:
        import jax  # only where this process imported it already

        if jax.config.jax_compilation_cache_dir:  # set in this process (jax.config.update)
            return Path(jax.config.jax_compilation_cache_dir)
    folder = cache_folder(env)
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(folder, os.W_OK) or not probe(folder):
        return None
    # JAX's size bound needs filelock (a dependency of softpinn; without it JAX would refuse to
    # open the cache, so the cache then grows without a bound instead)
    limit = MAX_BYTES if importlib.util.find_spec("filelock") is not None else -1
    env.update({"JAX_COMPILATION_CACHE_DIR": str(folder),
                "JAX_COMPILATION_CACHE_MAX_SIZE": str(limit)})
    if environ is None and "jax" in sys.modules:
        import jax  # only where this process imported it already

        # JAX opens its cache at the first compilation after a folder is set (tested)
        jax.config.update("jax_compilation_cache_dir", str(folder))
        jax.config.update("jax_compilation_cache_max_size", limit)
    return folder
