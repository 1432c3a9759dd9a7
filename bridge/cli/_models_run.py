"""``softpinn models``: one row per preset (its parser: :mod:`bridge.cli.models`)."""

from __future__ import annotations

from softpinn.symbolic import dumps, list_presets, load_spec


def run(args) -> int:
    rows = []
    for name in list_presets():
        spec = load_spec(name)
        rows.append(
            {
                "name": name,
                "kind": spec.kind,
                "n": spec.n,
                "m": spec.m,
                "description": spec.description,
            }
        )
    if args.json:
        print(dumps({"models": rows}, what="models"))
        return 0
    w = max(8, *(len(r["name"]) for r in rows))
    print(f"{'name':<{w}} {'kind':<20} {'n':>2} {'m':>2}  description")
    for r in rows:
        print(f"{r['name']:<{w}} {r['kind']:<20} {r['n']:>2} {r['m']:>2}  {r['description']}")
    return 0
