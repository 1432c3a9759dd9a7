"""``softpinn init``: a commented template spec (:func:`softpinn.symbolic.write_template`),
written atomically (its parser: :mod:`bridge.cli.init`)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from softpinn.errors import UserError
from softpinn.symbolic import write_template


def run(args) -> int:
    out = Path(args.out) if args.out else Path(f"{args.name}.toml")
    if out.suffix != ".toml":
        raise UserError(f"--out {out}: a spec file must end in .toml")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder, not a spec file")
    if out.exists() and not args.force:
        raise UserError(f"--out {out}: file exists (use --force to overwrite)")
    text, spec = write_template(args.name, args.segments, planar=args.planar,
                                hanging=args.hanging, actuation=args.actuation, file=str(out),
                                inputs=getattr(args, "inputs", None),
                                angles=getattr(args, "angles", None))
    _write_text(out, text)
    actuation = spec.actuation
    if not isinstance(actuation, str):
        kind = {"tendons": "tendon"}.get(args.actuation, args.actuation)
        actuation = f"{kind} (a constant {spec.n} x {spec.m} matrix)"
    print(f"{spec.name}: wrote {out} ({len(spec.segments)}-segment {spec.kind}, n = {spec.n}, "
          f"m = {spec.m}, actuation {actuation}); edit it, then:")
    print(f"  softpinn simulate {out} --out {spec.name}.npz")
    return 0


def _write_text(path: Path, text: str) -> None:
    """Write ``text`` atomically (temporary sibling, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except OSError as exc:
        raise UserError(f"--out {path}: cannot write ({exc.strerror or exc})") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)

