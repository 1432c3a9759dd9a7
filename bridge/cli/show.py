"""``softpinn show``: look at a PCC arm of a spec, at configurations or along a trajectory."""

from __future__ import annotations

from pathlib import Path

from softpinn.bridge.figures.arm import draw_configurations, shape_animation, shape_figure
from softpinn.errors import UserError
from softpinn.symbolic import PCC_KINDS, load_spec, read_dataset


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "show",
        help="draw a PCC arm's backbone at configurations, or animate a trajectory",
        description=(
            "Draw the backbone curve (eqs. 13-14, 27) of a planar or spatial PCC arm: at the "
            "configurations --q (a PNG), or along one trajectory of a dataset file --data (a GIF "
            "animation, or a PNG of four instants when --out ends in .png)."
        ),
    )
    p.add_argument("model", metavar="MODEL", help="preset name or spec file of a PCC arm")
    p.add_argument("--q", nargs="+", type=float, metavar="Q",
                   help="configurations, n numbers each (several: concatenate them)")
    p.add_argument("--data", metavar="DATA.npz", default=None,
                   help="a dataset file of this model: animate one of its trajectories")
    p.add_argument("--trajectory", type=int, default=None, metavar="ID",
                   help="the trajectory of --data to show (default: its first)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="the picture to write: .png, or .gif for an animation of --data")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=cmd_show)


def cmd_show(args) -> int:
    import numpy as np



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
