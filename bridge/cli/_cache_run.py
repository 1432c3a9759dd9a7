"""``softpinn cache``: what softpinn keeps between runs, and clearing it (its parser:
:mod:`bridge.cli.cache`).

Two caches, both safe to delete (whatever is missing is built again when next needed):

* compiled C (``$SOFTPINN_CACHE``, else ``~/.cache/softpinn``): the shared libraries of derived
  models, batched simulation kernels and controllers (:func:`softpinn.symbolic.cache_dir`), one
  folder per content hash;
* XLA's compiled programs (:mod:`softpinn.learn.jitcache`): one folder per machine and jaxlib
  build under ``$SOFTPINN_JIT_CACHE``, else ``jax/`` in the first.

``--clear`` removes only what softpinn wrote there (folders named by its hashes, unfinished
builds, the program cache's files): anything else in a folder a user pointed the variables at
stays.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

from softpinn.errors import UserError
from softpinn.learn import jitcache
from softpinn.symbolic import cache_dir

_CODE = re.compile(r"(kernel_)?[0-9a-f]{24}")
_BUILD = re.compile(r"\.build-.+")
_MACHINE = re.compile(r"[0-9a-f]{16}")
_PROGRAM_FILES = re.compile(r".+-(cache|atime)|probe\.json|probe\.\d+\.tmp|probe-\d+|\.lockfile")


def _size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def code_entries(root: Path) -> list[Path]:
    """The compiled-C cache's own entries in ``root``: hash-named folders and unfinished builds."""
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir()
                  and (_CODE.fullmatch(p.name) or _BUILD.fullmatch(p.name)))


def program_entries(base: Path) -> list[Path]:
    """The program cache's own files in each machine folder of ``base`` (``<16 hex>/``)."""
    if not base.is_dir():
        return []
    return sorted(f for d in base.iterdir() if d.is_dir() and _MACHINE.fullmatch(d.name)
                  for f in d.iterdir() if _PROGRAM_FILES.fullmatch(f.name))


def _remove(path: Path) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    except FileNotFoundError:  # gone already (another process cleared it)
        pass


def run(args) -> int:
    code_root = cache_dir()
    here = jitcache.cache_folder()  # None when SOFTPINN_JIT_CACHE is off
    programs_base = here.parent if here is not None else None
    code = code_entries(code_root)
    programs = program_entries(programs_base) if programs_base is not None else []
    mine = [p for p in programs if here is not None and p.parent == here]
    record = {
        "code": {"folder": str(code_root), "libraries": sum(1 for p in code if _CODE.fullmatch(
            p.name)), "bytes": sum(_size(p) for p in code)},
        "programs": {
            "folder": str(here) if here is not None else None,
            "programs": sum(1 for p in mine if p.name.endswith("-cache")),
            "bytes": sum(_size(p) for p in mine),
            "other_folders": len({p.parent for p in programs} - {here}),
            "other_bytes": sum(_size(p) for p in programs if p.parent != here),
            "probe": _probe(here),
        },
    }
    failed = []
    if args.clear:
        for p in code + programs:
            try:
                _remove(p)
            except OSError as exc:
                failed.append(f"{p}: {exc.strerror or type(exc).__name__}")
        for d in {p.parent for p in programs}:
            try:
                d.rmdir()  # only if softpinn's files were all there was
            except OSError:
                pass
        record["cleared"] = True
        record["failed"] = failed
    if args.json:
        print(json.dumps(record))
    else:
        _print(record, args.clear and not failed, here)
    if failed:
        raise UserError(f"could not remove {len(failed)} of the cached entries, e.g. {failed[0]}")
    return 0


def _print(record: dict, cleared: bool, here: Path | None) -> None:
    c, g = record["code"], record["programs"]
    verb = "removed " if cleared else ""
    print(f"compiled C (models, kernels, controllers): {c['folder']}")
    print(f"  {verb}{c['libraries']} libraries, {_mb(c['bytes'])}")
    if g["folder"] is None:
        print("XLA programs: off (SOFTPINN_JIT_CACHE)")
    else:
        print(f"XLA programs (this machine and jaxlib): {g['folder']}")
        print(f"  {verb}{g['programs']} programs, {_mb(g['bytes'])}"
              + (f"; {g['probe']}" if g["probe"] and not cleared else ""))
    if g["other_folders"]:
        print(f"  {verb}{g['other_folders']} other machines' or jaxlib builds' folders, "
              f"{_mb(g['other_bytes'])}")
    theirs = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if theirs and (here is None or Path(theirs) != here):
        print(f"JAX_COMPILATION_CACHE_DIR={theirs} is set: JAX keeps its programs there "
              "instead (a folder of yours: not listed or cleared here)")


def _probe(folder: Path | None) -> str | None:
    try:
        record = json.loads((folder / "probe.json").read_text())
    except (OSError, ValueError, TypeError):
        return None
    return ("checked: XLA loads its cached programs here" if record.get("ok")
            else f"off here: {record.get('why', 'XLA rejected its cached programs')}")


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"

