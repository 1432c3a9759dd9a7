"""Run directories and checkpoints, written atomically.

Every file is written to a temporary file in the same directory and installed with
``os.replace``, so an interrupted run always leaves the last complete version of each file.
Training state that must stay consistent (parameters, optimizer state, best parameters, epoch,
history) lives in ONE file, ``checkpoint.eqx``: a JSON header line followed by the Equinox
serialised leaves (``eqx.tree_serialise_leaves``), the pattern of Equinox's serialisation example.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import equinox as eqx

from .errors import UserError

#: Files a run directory may hold (``--force`` removes only these, and member folders).
RUN_FILES = (
    "config.json",
    "model.eqx",
    "checkpoint.eqx",
    "history.csv",
    "metrics.json",
    "loss.png",
)
MEMBER_PREFIX = "seed-"


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


def read_json(path: str | Path) -> Any:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON ({exc})") from None


def tree_to_bytes(tree, header: dict | None = None) -> bytes:
    """A JSON header line (possibly empty ``{}``) followed by the serialised leaves."""
    buf = io.BytesIO()
    buf.write((json.dumps(header or {}) + "\n").encode("utf-8"))
    eqx.tree_serialise_leaves(buf, tree)
    return buf.getvalue()


def save_tree(path: str | Path, tree, header: dict | None = None) -> Path:
    """Atomically write ``tree`` (any pytree of arrays) with an optional JSON ``header``."""
    return atomic_write_bytes(path, tree_to_bytes(tree, header))


def read_header(path: str | Path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return json.loads(f.readline().decode("utf-8"))
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)") from None


def load_tree(path: str | Path, like):
    """Read a file written by :func:`save_tree`; ``like`` gives the structure, shapes, dtypes.

    Returns ``(header, tree)``.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            header = json.loads(f.readline().decode("utf-8"))
            tree = eqx.tree_deserialise_leaves(f, like)
    except FileNotFoundError:
        raise UserError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise UserError(f"{path}: not a softpinn checkpoint (bad header)") from None
    except (RuntimeError, ValueError, OSError) as exc:
        raise UserError(f"{path}: does not match the model in config.json ({exc})") from None
    return header, tree


def write_history(path: str | Path, rows: list[dict]) -> Path:
    """``history.csv``: epoch, train_loss, test_loss, seconds, phase."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["epoch", "train_loss", "test_loss", "seconds", "phase"])
    for r in rows:
        w.writerow(
            [
                r["epoch"],
                repr(float(r["train_loss"])),
                repr(float(r["test_loss"])),
                f"{r['seconds']:.3f}",
                r.get("phase", "adamw"),
            ]
        )
    return atomic_write_text(path, buf.getvalue())


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
        }
        for r in rows
    ]


def prepare_run_dir(out_dir: str | Path, *, force: bool = False, resume: bool = False) -> Path:
    """Make sure ``out_dir`` may be written.

    A directory that holds anything is refused unless ``resume`` (continue it) or ``force``
    (remove the run files and member folders this program writes; nothing else is deleted).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserError(f"run directory {out} is a file")
    if resume:
        if not (out / "config.json").is_file():
            raise UserError(f"--resume: {out} holds no run to resume (no config.json)")
        return out
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise UserError(
                f"run directory {out} already exists and is not empty; "
                "use --force to overwrite it or --resume to continue it"
            )
        for name in RUN_FILES:
            (out / name).unlink(missing_ok=True)
        for p in out.glob(MEMBER_PREFIX + "*"):
            if p.is_dir() and (p / "config.json").exists():
                shutil.rmtree(p)
        for p in out.glob("*.png"):
            p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    return out
