"""Output folders of ``softpinn analyze`` and ``softpinn reproduce``: nothing of the user's is
overwritten or deleted.

A command claims its ``--out`` folder before it writes anything, by writing the folder's
``manifest.json`` (the format of a run directory's, :mod:`learn._checkpoint`, with the name of
the command that owns the folder); when it finishes, the manifest lists every file it wrote, with
its sha256. The folder may be new, empty, or one the same command claimed before (a rerun, or a
rerun after an interruption: the claim is written first, so an interrupted command never blocks
the next one). Any other non-empty folder (a user's, a run directory, another command's output)
is refused with one line unless ``--force``; ``--force`` writes into it and removes nothing. A
rerun is refused too where a file the finished command recorded has changed since (its user
edited it): the sha256 in the manifest tells.

The claim is exclusive (:mod:`softpinn.locks`): the command holds the folder's lock until it
ends, so a second writer of the same folder, started together with it or later, is refused
with one line naming the process that holds it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

from softpinn import locks
from softpinn.errors import UserError
from softpinn.files import NULL, jsonable, write_json
from softpinn.learn import file_sha256

MANIFEST = "manifest.json"
FORMAT = "softpinn-manifest"


def _read(folder: Path) -> dict | None:
    path = folder / MANIFEST
    if not path.is_file():
        return None
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return obj if isinstance(obj, dict) and obj.get("format") == FORMAT else {}


def owner(folder: Path) -> str | None:
    """The softpinn command whose output ``folder`` holds: ``analyze``, ``reproduce``, ``train``
    (a run directory), ``''`` for a folder holding things softpinn did not write, None if empty."""
    if not folder.is_dir() or not any(folder.iterdir()):
        return None
    manifest = _read(folder)
    if manifest:
        return str(manifest.get("command") or "train")
    if (folder / "config.json").is_file() and (folder / "model.eqx").is_file():
        return "train"
    # a task folder written before output folders had a manifest: its stages' records
    if any(folder.glob("*/done.json")) or (folder / "report.md").is_file() and any(
            folder.glob("*/*/done.json")):
        return "reproduce"
    return ""


def _describe(who: str) -> str:
    if who == "":
        return "files softpinn did not write"
    if who == "train":
        return "a run directory of softpinn train"
    return f"the output of softpinn {who}"


def _sha256(path: Path) -> str:

    return file_sha256(path)


def changed_files(out: str | Path) -> list[str]:
    """Files a finished command recorded in ``out``'s manifest that have changed since (edited
    by their user). Empty where the manifest is not a finished command's: after an interrupted
    run, a file it rewrote and had no time to record is not anybody's edit."""
    out = Path(out)
    manifest = _read(out) or {}
    if manifest.get("complete") is not True:
        return []
    changed = []
    for name, sha in manifest.get("files", {}).items():
        path = out / name
        try:
            if path.is_file() and _sha256(path) != sha:
                changed.append(name)
        except OSError:
            continue
    return changed


def check_parent(out: str | Path, flag: str) -> None:
    """Refuse, with one line naming ``flag``, an output path that cannot be made: its nearest
    existing ancestor is a file, or (for a path not there yet) a folder without write
    permission."""
    out = Path(out)
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UserError(f"{flag}: {out}: cannot write there ({parent} is a file, not "
                                "a folder)")
            if not out.exists() and not os.access(parent, os.W_OK | os.X_OK):
                raise UserError(f"{flag}: {out}: cannot write there (no write permission in "
                                f"{parent})")
            return


def check(out: str | Path, command: str, *, force: bool = False) -> str | None:
    """Refuse, with one line, an ``out`` that ``command`` may not write into (see the module's
    docstring; also a file of an earlier output of ``command`` that its user has edited since);
    return the folder's owner (:func:`owner`). Writes nothing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"out: {out} is a file, not a folder")
    check_parent(out, "out")
    locks.check_free(out, flag="out")
    who = owner(out)
    if who is not None and who != command and not force:
        raise UserError(
            f"out: {out} already holds {_describe(who)}; choose another folder, or --force to "
            "write into it (nothing of yours is removed)"
        )
    if who == command and not force:
        changed = changed_files(out)
        if changed:
            more = f" (and {len(changed) - 1} more)" if len(changed) > 1 else ""
            raise UserError(
                f"out: {out / changed[0]}{more} changed after softpinn {command} wrote it; "
                "move it away, or --force to write over it"
            )
    return who


def claim(out: str | Path, command: str, *, force: bool = False) -> Path:
    """Make ``out`` the output folder of ``command`` (see the module's docstring); the
    command holds its lock (:func:`softpinn.locks.hold`) until it ends."""
    out = Path(out)
    check(out, command, force=force)  # a refused command takes nothing
    taken = locks.hold(out, command, flag="out")
    try:
        who = check(out, command, force=force)  # again, held: another writer may have ended
        out.mkdir(parents=True, exist_ok=True)
        previous = (_read(out) or {}).get("files", {}) if who == command else {}
        # not complete until record(): an interrupted run's rewritten files are its own
        _write(out, {"format": FORMAT, "command": command, "files": previous,
                     "complete": False})
    except OSError as exc:
        if taken:
            locks.release(out)
        raise UserError(f"out: {out}: cannot write there ({exc.strerror or exc})") from None
    except BaseException:
        if taken:
            locks.release(out)
        raise
    return out


def hold(path: str | Path, command: str) -> None:
    """Hold the exclusive claim on ``path`` (a dataset file, or a folder a command writes
    whole: ``derive``, ``export``) until ``command`` ends (:func:`softpinn.locks.hold`): a
    second writer is refused with one line naming the process that holds it."""
    locks.hold(path, command, flag="out")


def record(out: str | Path, paths: Iterable[str | Path]) -> None:
    """List ``paths`` (files under ``out``) in its manifest with their sha256."""
    out = Path(out)
    manifest = _read(out) or {"format": FORMAT}
    files = dict(manifest.get("files", {}))
    root = out.resolve()
    for p in paths:
        p = Path(p)
        if not p.is_file():
            continue
        try:
            name = p.resolve().relative_to(root).as_posix()
        except ValueError:
            continue
        files[name] = _sha256(p)
    manifest["files"] = dict(sorted(files.items()))
    manifest["complete"] = True
    _write(out, manifest)


def written_files(out: str | Path) -> list[Path]:
    """Every file under ``out`` (what a command that owns the whole folder wrote)."""
    return sorted(p for p in Path(out).rglob("*") if p.is_file() and p.name != MANIFEST
                  and not p.name.startswith("."))


def _write(out: Path, manifest: dict) -> None:
    """The manifest, written whole (:func:`softpinn.files.write_json`; readable as the user's
    files are)."""
    path = out / MANIFEST
    try:
        write_json(path, manifest)
    except OSError as exc:
        raise UserError(f"{path}: cannot write there ({exc.strerror or exc})") from None


def to_jsonable(x):
    """``x`` as JSON without NaN or inf (results.json of the analyses, the challenge studies and
    `control`): arrays and tuples to lists, numpy scalars to Python, non-finite floats to None
    (the rule of files, :data:`softpinn.files.NULL`), enums and paths to str, keys to str."""
    return jsonable(x, nonfinite=NULL, str_keys=True)
