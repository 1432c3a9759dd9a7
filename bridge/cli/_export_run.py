"""``softpinn export``: flags mapped onto :func:`softpinn.bridge.export.export_run`, the stages
on stderr as they start (its parser: :mod:`bridge.cli.export`)."""

from __future__ import annotations

import json
import sys

from softpinn.bridge.base import outputs
from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.export import check_timeout, export_run


def run(args) -> int:
    check_timeout(args.compile_timeout)  # one line before any work
    enable_x64()

    def log(text):
        if not args.json:
            print(f"export: {text}", file=sys.stderr, flush=True)

    outputs.hold(args.out, "export")  # one writer of --out at a time (softpinn.locks)
    result = export_run(args.run, args.out, member=args.member, mean=args.mean, force=args.force,
                        log=log, compile=not args.no_compile,
                        compile_timeout=args.compile_timeout)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        lib = result["c"]["library"] or ("no library (--no-compile)" if args.no_compile
                                         else "no library (no C compiler)")
        seeds = ", ".join(str(s) for s in result["ensemble"]["seeds"])
        averaged = result["ensemble"]["mode"] == "mean"
        if args.mean and not averaged:
            print(f"softpinn: note: {args.run} holds one model: --mean exports that one",
                  file=sys.stderr)
        print(f"exported {result['kind']} model (n={result['n']}, m={result['m']}, seed(s) "
              f"{seeds}{', mean' if averaged else ''}) to {args.out}: "
              f"{len(result['functions'])} Functions, model.c/model.h, {lib}")
        act = result.get("actuator") or {}
        if act and not act.get("identity", True):
            print(f"actuator: {act['note']}")
    return 0
