"""``softpinn import``: recordings (CSV) into a dataset file
(:func:`softpinn.symbolic.import_recordings`; its parser: :mod:`bridge.cli.import_`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from softpinn.bridge.base import outputs
from softpinn.errors import UserError
from softpinn.symbolic import import_recordings, write_dataset


def run(args) -> int:
    out = Path(args.out)
    if out.is_dir():  # issue 44: --force writes over a file, never a folder
        raise UserError(f"--out {out}: is a folder; give a file name ending in .npz (e.g. "
                        f"{out / 'data.npz'})")
    if out.suffix != ".npz":
        raise UserError(f"--out {out}: a dataset file must end in .npz")
    outputs.check_parent(out, "--out")
    if out.exists() and not args.force:
        raise UserError(f"--out {out}: file exists (use --force to overwrite)")
    outputs.hold(out, "import")  # one writer of --out at a time (softpinn.locks)
    result = import_recordings(
        args.files,
        args.model,
        orientation_kind=args.orientation,
        smooth=args.smooth,
        rate=args.rate,
        test_trajectories=args.test_trajectories,
        differences=args.differences,
        observed_only=args.observed_only,
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

