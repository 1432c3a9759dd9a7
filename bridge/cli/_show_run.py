"""``softpinn show``: a PCC arm drawn at configurations (PNG) or along a trajectory (GIF, or a PNG
of four instants) (its parser: :mod:`bridge.cli.show`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softpinn.bridge.figures.arm import draw_configurations, shape_animation, shape_figure
from softpinn.errors import UserError
from softpinn.symbolic import PCC_KINDS, load_spec, read_dataset


def run(args) -> int:
    if (args.q is None) == (args.data is None):
        raise UserError("give --q (configurations) or --data (a trajectory), one of the two")
    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".gif") or (args.q is not None and suffix != ".png"):
        raise UserError(f"out: {out}: expected a .png{' or .gif' if args.data else ''} file")
    if out.is_dir():
        raise UserError(f"out: {out} is a folder, not a file")
    if out.exists() and not args.force:
        raise UserError(f"out: {out} exists; choose another name, or --force to replace it")
    if not out.parent.is_dir():
        raise UserError(f"out: {out.parent} is not a folder")
    spec = load_spec(args.model)
    if spec.kind not in PCC_KINDS:
        raise UserError(f"model: {spec.name} is a {spec.kind}, not a PCC arm: nothing to draw")
    if args.q is not None:
        if len(args.q) % spec.n:
            raise UserError(f"q: expected a multiple of n = {spec.n} numbers for {spec.name}, "
                            f"got {len(args.q)}")
        q = np.asarray(args.q, float).reshape(-1, spec.n)
        path = draw_configurations(spec, q, path=out)
        print(f"wrote {path} ({len(q)} configuration(s) of {spec.name})")
        return 0
    data = read_dataset(args.data)
    if data.q.shape[1] != spec.n:
        raise UserError(f"data: {args.data} holds n = {data.q.shape[1]} coordinates; "
                        f"{spec.name} has n = {spec.n}")
    ids = data.trajectory_ids
    tid = int(ids[0]) if args.trajectory is None else args.trajectory
    if tid not in set(ids.tolist()):
        raise UserError(f"trajectory: {tid} is not in {args.data} (ids {ids.min()}..{ids.max()})")
    rows = data.traj == tid
    t, q = data.t[rows], data.q[rows]
    title = f"{spec.name}: trajectory {tid} of {Path(args.data).name}"
    if suffix == ".gif":
        path = shape_animation(spec, t, q, {}, path=out, title=title)
    else:
        path = shape_figure(spec, t, q, {}, path=out, title=title, pdf=False)
    print(f"wrote {path} (trajectory {tid}, {t[-1] - t[0]:.3g} s)")
    return 0

