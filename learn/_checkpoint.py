"""Run directories and checkpoints, written atomically.

Every file is written to a temporary file of its own in the same directory and installed with
``os.replace`` (:mod:`softpinn.files`), so an interrupted run always leaves the last complete
version of each file.
Training state that must stay consistent (parameters, optimizer state, best parameters, epoch,
history) lives in ONE file, ``checkpoint.eqx``: a JSON header line followed by the Equinox
serialised leaves (``eqx.tree_serialise_leaves``), the pattern of Equinox's serialisation example.

Integrity: the header of every ``.eqx`` file carries the sha256 of its leaves (and of the rest
of the header), checked when the file is read, so that a corrupted model or checkpoint is refused
with one line instead of loading garbage. Every file written into a run directory is listed in
its ``manifest.json`` (name -> sha256) before it is written; ``--force`` removes only those.
JSON files never hold NaN or Infinity: non-finite numbers are written as null (the rule of
:mod:`softpinn.files`).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from pathlib import Path
from typing import Any

import equinox as eqx
import jax

from softpinn import locks
from softpinn.errors import UserError
from softpinn.files import atomic_write, json_text

#: The list of files softpinn wrote into a run directory (name -> sha256).
MANIFEST = "manifest.json"
#: Files a run directory written before the manifest existed may hold (``--force`` removes only
#: these and member folders when a run has no manifest).
RUN_FILES = (
    "config.json",
    "model.eqx",
    "checkpoint.eqx",
    "history.csv",
    "metrics.json",
    "loss.png",
    MANIFEST,
)
MEMBER_PREFIX = "seed-"


def cannot_write(path: Path, exc: OSError) -> UserError:
    """The one-line error for a file or folder that cannot be written (inside a file, no
    permission, disk full, ...)."""
    return UserError(f"{path}: cannot write there ({exc.strerror or exc})")


def atomic_write_bytes(path: str | Path, data: bytes, *, record: bool = False) -> Path:
    """Write ``data`` to ``path`` whole (:func:`softpinn.files.atomic_write`: a temporary file
    of its own, fsync, ``os.replace``; an error leaves the previous file).

    ``record``: list the file in the ``manifest.json`` of its folder (run directories)."""
    path = Path(path)
    try:
        if record:
            path.parent.mkdir(parents=True, exist_ok=True)
            _record(path, data)
        return atomic_write(path, data)
    except OSError as exc:
        raise cannot_write(path, exc) from None


def _record(path: Path, data: bytes) -> None:
    """Add ``path`` (with the sha256 of ``data``) to its folder's manifest, BEFORE the file is
    written: a file that exists was always listed first."""
    mpath = path.parent / MANIFEST
    files = read_manifest(path.parent) or {}
    files[path.name] = hashlib.sha256(data).hexdigest()
    text = json_text({"format": "softpinn-manifest", "files": files})
    atomic_write_bytes(mpath, text.encode("utf-8"))


def read_manifest(folder: str | Path) -> dict[str, str] | None:
    """``{name: sha256}`` of the files softpinn wrote into ``folder`` (None: no manifest)."""
    mpath = Path(folder) / MANIFEST
    if not mpath.is_file():
        return None
    try:
        files = json.loads(mpath.read_text())["files"]
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        raise UserError(f"{mpath}: not a softpinn manifest") from None
    if not isinstance(files, dict):
        raise UserError(f"{mpath}: not a softpinn manifest")
    return files


def atomic_write_text(path: str | Path, text: str, *, record: bool = False) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), record=record)


def atomic_write_json(path: str | Path, obj: Any, *, record: bool = False) -> Path:
    """Strict JSON (:func:`softpinn.files.json_text`: non-finite numbers as null), written
    whole."""
    return atomic_write_text(path, json_text(obj), record=record)


def read_json(path: str | Path) -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON ({exc})") from None


def _digest(header: dict, payload: bytes) -> str:
    """sha256 of the header (without its digest, keys sorted) and the serialised leaves."""
    h = hashlib.sha256(json.dumps(header, sort_keys=True).encode("utf-8"))
    h.update(payload)
    return h.hexdigest()


def tree_to_bytes(tree, header: dict | None = None) -> bytes:
    """A JSON header line followed by the serialised leaves; the header carries ``sha256``,
    the digest of the rest of the header and of the leaves."""
    leaves = io.BytesIO()
    eqx.tree_serialise_leaves(leaves, tree)
    payload = leaves.getvalue()
    header = dict(header or {})
    header.pop("sha256", None)
    head = {**header, "sha256": _digest(header, payload)}
    return (json.dumps(head) + "\n").encode("utf-8") + payload


def save_tree(path: str | Path, tree, header: dict | None = None, *, record: bool = False
              ) -> Path:
    """Atomically write ``tree`` (any pytree of arrays) with an optional JSON ``header``."""
    return atomic_write_bytes(path, tree_to_bytes(tree, header), record=record)


def read_header(path: str | Path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as f:
            header = json.loads(f.readline().decode("utf-8"))
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)") from None
    if not isinstance(header, dict):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)")
    header.pop("sha256", None)
    return header


def load_tree(path: str | Path, like):
    """Read a file written by :func:`save_tree`; ``like`` gives the structure, shapes, dtypes.

    Returns ``(header, tree)``.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            header = json.loads(f.readline().decode("utf-8"))
            payload = f.read()
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)") from None
    if not isinstance(header, dict):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)")
    stored = header.pop("sha256", None)  # files written before checksums have none
    if stored is not None and stored != _digest(header, payload):
        raise UserError(
            f"{path}: checksum mismatch, the file is corrupted (sha256 of its content differs "
            "from the one stored in it); retrain, or resume from an intact checkpoint"
        )
    try:
        tree = eqx.tree_deserialise_leaves(io.BytesIO(payload), like)
    except (RuntimeError, ValueError, OSError) as exc:
        raise UserError(f"{path}: does not match the model in config.json ({exc})") from None
    return header, tree


def write_history(path: str | Path, rows: list[dict], *, record: bool = False) -> Path:
    """``history.csv``: epoch, train_loss, test_loss, seconds, phase (and validation_loss, the
    loss that picked the model, in a run that held out validation trajectories)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    val = any("validation_loss" in r for r in rows)
    w.writerow(["epoch", "train_loss", "test_loss", "seconds", "phase"]
               + (["validation_loss"] if val else []))
    for r in rows:
        w.writerow(
            [
                r["epoch"],
                repr(float(r["train_loss"])),
                repr(float(r["test_loss"])),
                f"{r['seconds']:.3f}",
                r.get("phase", "adamw"),
            ] + ([repr(float(r.get("validation_loss", "nan")))] if val else [])
        )
    return atomic_write_text(path, buf.getvalue(), record=record)


def read_history(path: str | Path) -> list[dict]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return [
        {
            "epoch": int(r["epoch"]),
            "train_loss": float(r["train_loss"]),
            "test_loss": float(r["test_loss"]),
            "seconds": float(r["seconds"]),
            "phase": r.get("phase", "adamw"),
            **({"validation_loss": float(r["validation_loss"])} if r.get("validation_loss")
               else {}),
        }
        for r in rows
    ]


def check_run_dir(out_dir: str | Path, *, force: bool = False, resume: bool = False) -> Path:
    """The refusals of :func:`prepare_run_dir`, without writing or removing anything (so that a
    command can give them before its work starts); also a folder another process is training
    into (:func:`softpinn.locks.check_free`)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"run directory {out} is a file")
    if _shared_writer():
        locks.check_free(out, flag="out")
    if not out.exists():
        for parent in out.parents:
            if parent.exists():
                if not parent.is_dir():
                    raise UserError(f"run directory {out}: {parent} is a file, not a folder")
                break
    if resume:
        if not (out / "config.json").is_file():
            raise UserError(f"--resume: {out} holds no run to resume (no config.json)")
        return out
    if out.is_dir() and any(out.iterdir()) and not force:
        raise UserError(
            f"run directory {out} already exists and is not empty; "
            "use --force to overwrite it or --resume to continue it"
        )
    return out


def prepare_run_dir(out_dir: str | Path, *, force: bool = False, resume: bool = False) -> Path:
    """Make sure ``out_dir`` may be written.

    A directory that holds anything is refused unless ``resume`` (continue it) or ``force``
    (remove the files its manifest lists, i.e. those softpinn wrote, and member folders; a run
    without a manifest loses only the names in :data:`RUN_FILES`; nothing else is deleted).

    The folder is claimed (:func:`softpinn.locks.hold`) until the end of the caller's
    :func:`softpinn.locks.scope` (``learn.train`` runs in one) or of the process: a second
    writer is refused with one line naming this one.
    """
    out = check_run_dir(out_dir, force=force, resume=resume)  # a refused run takes nothing
    taken = locks.hold(out, "train", flag="out")
    try:
        # again, held: another run may have ended in it since
        out = check_run_dir(out_dir, force=force, resume=resume)
        if resume:
            return out
        if out.is_dir() and any(out.iterdir()):
            for p in out.glob(MEMBER_PREFIX + "*"):
                if p.is_dir() and (p / "config.json").exists():
                    remove_written(p)
            remove_written(out)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise cannot_write(out, exc) from None
    except BaseException:
        if taken:
            locks.release(out)
        raise
    return out


def _shared_writer() -> bool:
    """Whether this process writes the run directories of its command: the only process, or
    process 0 of several (the others write private copies, :mod:`learn.distributed`)."""
    return not jax.distributed.is_initialized() or jax.process_index() == 0


def remove_written(folder: Path) -> None:
    """Remove the files softpinn wrote into ``folder`` (its manifest's, else :data:`RUN_FILES`),
    the manifest last, and the folder itself if that leaves it empty and it is a member folder."""
    files = read_manifest(folder)
    names = list(RUN_FILES) if files is None else [n for n in files if n != MANIFEST]
    for name in names:
        if "/" in name or name in ("", ".", ".."):
            continue
        (folder / name).unlink(missing_ok=True)
    (folder / MANIFEST).unlink(missing_ok=True)
    if folder.name.startswith(MEMBER_PREFIX) and not any(folder.iterdir()):
        folder.rmdir()
