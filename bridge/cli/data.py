"""``softpinn`` subcommands for an arm of one's own: ``import`` and ``init`` (docs/import.md).

* ``import REC.csv [...] --model MODEL --out DATA.npz``: recorded trajectories (configurations,
  or tip orientation from an IMU) into a dataset file
  (:func:`symbolic.recorded._import.import_recordings`);
* ``init NAME --segments K``: a commented template spec (:func:`symbolic.recorded._template.write_template`).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

from softpinn.errors import UserError
from softpinn.symbolic import import_recordings, write_dataset, write_template


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "import",
        help="turn recorded trajectories (CSV) into a dataset file (.npz)",
        description="Read recordings of an arm (CSV with a header row: t, u0.., and q0.. or the "
        "tip orientation), smooth them, take velocities and accelerations, optionally resample, "
        "and write a dataset file that 'softpinn train' reads. The format is in docs/import.md.",
    )
    p.add_argument("files", nargs="+", metavar="REC.csv",
                   help="recordings: one trajectory per file, or several told apart by an "
                   "integer 'traj' column")
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="preset name or spec file of the arm: its n coordinates and m inputs, and "
                   "its mass matrix for the momentum p = M(q) qd")
    p.add_argument("--out", required=True, metavar="DATA.npz", help="dataset file to write")
    p.add_argument("--orientation", choices=("quaternion", "rpy"),
                   help="the state is the tip orientation: columns qw,qx,qy,qz or roll,pitch,yaw "
                   "[rad], mapped to the bending of a one-segment spatial PCC arm (the stretch "
                   "is set to 0); default: configuration columns q0..")
    p.add_argument("--smooth", default="none", metavar="METHOD",
                   help="none | movmean:W (MATLAB's movmean, W samples) | savgol:W:P "
                   "(Savitzky-Golay) | polyfit:DEG:W (polynomials over runs of W samples)")
    p.add_argument("--differences", type=int, choices=(2, 4), default=2, metavar="ORDER",
                   help="order of the central differences that give velocities and "
                   "accelerations where the smoother has no derivative of its own (none, "
                   "movmean): 2 (3 samples) or 4 (5 samples: less bias at low rates, 1.34x the "
                   "noise; docs/import.md) (default: %(default)s)")
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="resample every trajectory to this uniform rate after smoothing "
                   "(default: keep the recorded times)")
    p.add_argument("--test-trajectories", type=int, default=0, metavar="K",
                   help="the last K trajectories form the test split recorded in meta (the "
                   "paper: the last 8 of 128)")
    p.add_argument("--force", action="store_true", help="overwrite an existing DATA.npz")
    p.add_argument("--json", action="store_true",
                   help="print the import's record (meta['import']) as one JSON object")
    p.set_defaults(func=cmd_import)

    p = subparsers.add_parser(
        "init",
        help="write a commented template spec for an arm of your own",
        description="Write a model spec (TOML) of a PCC arm with K segments, every field "
        "commented, to edit into your arm. Without a [data] table 'softpinn simulate' takes "
        "defaults from its physics; the template shows them, commented out.",
    )
    p.add_argument("name", metavar="NAME", help="the arm's name (letters, digits, _ - .)")
    p.add_argument("--segments", type=int, required=True, metavar="K",
                   help="number of PCC segments, base to tip")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--spatial", dest="planar", action="store_false",
                      help="a spatial arm, [dx, dy, dL] per segment (the default)")
    kind.add_argument("--planar", dest="planar", action="store_true",
                      help="a planar arm, [theta, dL] per segment")
    p.set_defaults(planar=False)
    p.add_argument("--hanging", action="store_true",
                   help="the arm hangs down (default: it stands up)")
    p.add_argument("--actuation", choices=("tendon", "generalized", "tip-wrench", "none"),
                   help="the inputs (default: tendon for a spatial arm, generalized for a planar "
                   "one)")
    p.add_argument("--out", metavar="FILE.toml", help="file to write (default: NAME.toml)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=cmd_init)


# --------------------------------------------------------------------------------------------


def cmd_import(args) -> int:

    out = Path(args.out)
    if out.suffix != ".npz":
        raise UserError(f"--out {out}: a dataset file must end in .npz")
    if out.exists() and not args.force:
        raise UserError(f"--out {out}: file exists (use --force to overwrite)")
    result = import_recordings(
        args.files,
        args.model,
        orientation_kind=args.orientation,
        smooth=args.smooth,
        rate=args.rate,
        test_trajectories=args.test_trajectories,
        differences=args.differences,
    )
    data = result.data
    write_dataset(out, data, force=args.force)
    record = data.meta["import"]
    if args.json:
        print(json.dumps(record))
        return 0
    for note in result.notes:
        print(f"softpinn: note: {note}", file=sys.stderr)
    meta = data.meta
    k = meta["trajectories"]
    rate = f"{meta['rate']:g} Hz" if meta["rate"] else "non-uniform times"
    test = meta["splits"]["test"]
    print(
        f"{meta['spec']['name']}: wrote {out} ({k} trajector{'y' if k == 1 else 'ies'}, "
        f"{len(data)} samples, {rate}, "
        f"state from {record['state']}, smooth {record['smooth']['text']}, "
        f"{len(test)} for test)"
    )
    hint = f" --test-trajectories {' '.join(map(str, test))}" if test else ""
    print(f"  next: softpinn train {out} --model lagrangian --out RUN{hint}")
    return 0


def cmd_init(args) -> int:

    out = Path(args.out) if args.out else Path(f"{args.name}.toml")
    if out.suffix != ".toml":
        raise UserError(f"--out {out}: a spec file must end in .toml")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder, not a spec file")
    if out.exists() and not args.force:
        raise UserError(f"--out {out}: file exists (use --force to overwrite)")
    text, spec = write_template(args.name, args.segments, planar=args.planar,
                                hanging=args.hanging, actuation=args.actuation, file=str(out))
    _write_text(out, text)
    print(f"{spec.name}: wrote {out} ({len(spec.segments)}-segment {spec.kind}, n = {spec.n}, "
          f"m = {spec.m}, actuation {spec.actuation}); edit it, then:")
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
