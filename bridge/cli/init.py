"""``softpinn init NAME --segments K``: a commented template spec of an arm of one's own
(docs/import.md); run in :mod:`bridge.cli._init_run`."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "init",
        help="write a commented template spec for an arm of your own",
        description="Write a model spec (TOML) of a PCC arm with K segments, every field "
        "commented, to edit into your arm. Without a [data] table 'softpinn simulate' takes "
        "defaults from its physics; the template shows them, commented out.",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
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
    p.add_argument("--actuation", choices=("tendon", "tendons", "chambers", "torques",
                                           "generalized", "tip-wrench", "none"),
                   help="the inputs (default: tendon for a spatial arm, generalized for a planar "
                   "one): tendon(s) = tensions [N]; chambers = pneumatic chamber pressures [kPa] "
                   "at --angles; torques = bending torques [N m] per segment; the others as "
                   "docs/spec.md")
    p.add_argument("--inputs", type=int, metavar="N",
                   help="tendons or chambers per segment (default: 4 tendons, 3 chambers, "
                   "evenly spaced)")
    p.add_argument("--angles", type=float, nargs="+", metavar="DEG",
                   help="the tendons' or chambers' angles [deg] around the backbone in each "
                   "segment's frame, from +x toward +y (e.g. 0 120 240); written as a constant "
                   "actuation matrix")
    p.add_argument("--out", metavar="FILE.toml", help="file to write (default: NAME.toml)")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")


def run(args) -> int:
    from softpinn.bridge.cli import _init_run  # deferred: casadi at start-up

    return _init_run.run(args)
