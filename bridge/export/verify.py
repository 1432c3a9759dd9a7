"""The checksums of an export (issue 44): ``softpinn export`` records the sha256 of every file
it writes (the ``.casadi`` Functions, ``model.c``/``model.h``, the library) in ``model.json``'s
``sha256`` table, and every loader checks them here before CasADi sees a file: a flipped bit in
a serialized Function can crash the loading process or load silently with wrong outputs.

An export written before the checksums (no ``sha256`` in its ``model.json``) still loads,
unverified (:func:`read_export` says so).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from pathlib import Path

from softpinn.errors import UserError

__all__ = ["CHECKSUMS", "file_checksums", "read_export"]

#: the key of ``model.json``'s table {file name: sha256 hex digest}
CHECKSUMS = "sha256"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_checksums(out: Path, names: Iterable[str]) -> dict[str, str]:
    """{name: sha256} of the files ``names`` in ``out`` (sorted by name)."""
    return {name: _sha256(Path(out) / name) for name in sorted(set(names))}


def read_export(out_dir) -> tuple[dict, bool]:
    """``(model.json, verified)`` of an export directory, after checking the sha256 of every
    file ``model.json`` lists: a changed or missing file is refused with one line naming it.
    ``verified`` is False for an export written before the checksums (nothing to check
    against)."""
    out = Path(out_dir)
    meta_path = out / "model.json"
    if not meta_path.is_file():
        raise UserError(f"{out}: not a softpinn export directory (no model.json)")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise UserError(f"{meta_path}: cannot be read ({exc}); export the run again") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("functions"), dict):
        raise UserError(f"{meta_path}: not a softpinn export's model.json (no functions); "
                        "export the run again")
    sums = meta.get(CHECKSUMS)
    if sums is None:
        return meta, False
    if not isinstance(sums, dict) or not all(isinstance(v, str) for v in sums.values()):
        raise UserError(f"{meta_path}: its {CHECKSUMS} table is damaged; export the run again")
    for name, expected in sums.items():
        path = out / name
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise UserError(f"{meta_path}: lists {name!r}, not a file of the export")
        if not path.is_file():
            raise UserError(f"{path}: missing (model.json lists it); copy the whole export, "
                            "or export the run again")
        try:
            actual = _sha256(path)
        except OSError as exc:
            raise UserError(f"{path}: cannot be read ({exc.strerror or exc})") from None
        if actual != expected:
            raise UserError(f"{path}: changed since softpinn export wrote it (sha256 "
                            f"{actual[:12]}..., model.json says {expected[:12]}...); export "
                            "the run again")
    return meta, True
