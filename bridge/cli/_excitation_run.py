"""``softpinn excitation``: the inertial, damping and other forces of a data set along each
direction of the true mass matrix (:func:`bridge.analysis.excitation.inertial_share`), as a
table or JSON (its parser: :mod:`bridge.cli.excitation`)."""

from __future__ import annotations

import json

from softpinn.bridge.analysis.excitation import (
    WEAK,
    data_share,
    mostly,
    ratio_text,
    weak_directions,
)
from softpinn.bridge.base.outputs import to_jsonable
from softpinn.errors import UserError
from softpinn.learn import load_dataset
from softpinn.symbolic import TrueModel, load_spec


def run(args) -> int:
    if str(args.model).endswith(".npz") and not str(args.data).endswith(".npz"):
        raise UserError(f"excitation DATA.npz MODEL: {args.model} is a data set and {args.data} "
                        f"a model; give the data set first")
    if args.samples < 1:
        raise UserError(f"--samples: expected a positive count, got {args.samples}")
    spec = load_spec(args.model)
    data = load_dataset(args.data, n=spec.n, m=spec.m)
    share, samples = data_share(TrueModel(spec), data, args.trajectories, count=args.samples)
    ids = sorted(set(int(i) for i in data.traj)) if args.trajectories is None \
        else sorted(set(args.trajectories))
    record = data.meta.get("import") if isinstance(data.meta, dict) else None
    unobserved = [c for c in (record or {}).get("unobserved", []) if c in spec.coordinate_names]
    if args.json:
        print(json.dumps(to_jsonable({  # NaN and inf as null
            "model": spec.name, "data": str(args.data), "samples": samples, "trajectories": ids,
            "coordinates": list(spec.coordinate_names), "unobserved": unobserved, **share})))
        return 0
    for line in _table(spec, share, args.data, samples, len(ids), unobserved):
        print(line)
    return 0


def _blind(vector, names, unobserved) -> bool:
    """Whether a direction moves a coordinate the data do not observe (import set it to 0)."""
    return any(vector[names.index(c)] >= 0.3 for c in unobserved)


def _table(spec, share: dict, path, samples: int, trajectories: int,
           unobserved=()) -> list[str]:
    names = list(spec.coordinate_names)
    lines = [f"{spec.name} on {path}: {samples} samples of {trajectories} trajector"
             f"{'y' if trajectories == 1 else 'ies'}; directions of the true M(q), lightest first",
             f"{'':3} {'mostly':<12} {'M eigenvalue':>12} {'corner':>9} {'inertia':>9} "
             f"{'damping':>9} {'rest':>9} {'inertia/damping':>16}"]
    blind = [i + 1 for i, vec in enumerate(share["vectors"]) if _blind(vec, names, unobserved)]
    for i, vec in enumerate(share["vectors"]):
        ratio = "not observed" if i + 1 in blind else ratio_text(share["inertia_over_damping"][i])
        lines.append(
            f"{i + 1:>3} {mostly(vec, names):<12} {share['eigenvalue'][i]:>12.3g} "
            f"{share['corner_hz'][i]:>6.3g} Hz {share['inertial'][i]:>9.3g} "
            f"{share['damping'][i]:>9.3g} {share['rest'][i]:>9.3g} {ratio:>16}")
    weak = [i for i in weak_directions(share) if i not in blind]
    if blind:
        lines.append(
            f"not observed: {', '.join(unobserved)} (the recording cannot measure "
            f"{'it' if len(unobserved) == 1 else 'them'}; import set the value to 0), so "
            f"direction{'s' if len(blind) > 1 else ''} {', '.join(map(str, blind))} say nothing "
            "of the arm")
    if weak:
        corner = max(share["corner_hz"][i - 1] for i in weak)
        lines.append(
            f"weakly excited: direction{'s' if len(weak) > 1 else ''} "
            f"{', '.join(map(str, weak))} (inertia under {100 * WEAK:g} % of damping): the data "
            f"fix M there only as well as the other forces are fitted; inputs reaching toward "
            f"the corner frequency ({corner:.3g} Hz) show it (docs/challenges.md, \"Data that "
            f"show the mass\")")
    else:
        lines.append(f"every {'observed ' if blind else ''}direction shows its inertia (at "
                     f"least {100 * WEAK:g} % of its damping, or no damping along it)")
    return lines

