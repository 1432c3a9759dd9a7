"""``softpinn predict``: flags mapped onto :func:`softpinn.learn.predict`; the errors, and what
the run's numbers need said beside them (:mod:`bridge.cli.runnotes`; its parser:
:mod:`bridge.cli.predict`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

from softpinn.bridge.cli._jax import enable_x64
from softpinn.bridge.cli.runnotes import member_notes, note_interrupted, ran_away_text
from softpinn.errors import UserError
from softpinn.learn import predict


def run(args) -> int:
    enable_x64()

    if Path(args.run).is_file() and Path(args.data).is_dir():
        raise UserError(f"RUN {args.run} is a file and DATA {args.data} a folder; the order is "
                        "`softpinn predict RUN DATA.npz`")

    traj = args.trajectories
    if len(traj) == 1 and traj[0] in ("auto", "test", "all"):
        traj = traj[0]
    else:
        try:
            traj = [int(t) for t in traj]
        except ValueError:
            raise UserError(
                f"--trajectories takes 'test', 'all' or integer ids, got {' '.join(traj)}"
            ) from None
    res = predict(
        args.run,
        args.data,
        horizon=args.horizon,
        reset_every=args.reset_every,
        dt=args.dt,
        trajectories=traj,
        member=args.member,
        plot=args.plot,
        force=args.force,
    )
    out = res.to_json()
    note_interrupted(out["run"])
    for note in member_notes(args.run, SimpleNamespace(seed=out["seed"]), args.member):
        print(f"softpinn: note: {note}", file=sys.stderr)
    if args.json:
        print(json.dumps(out, allow_nan=False))
        return 0
    one = out["one_step_error"]
    fmt = lambda x: "inf" if x is None else f"{x:.4e}"
    print(f"one-step error: {fmt(one['mean'])} ± {fmt(one['std'])} over {one['pairs']} pairs")
    extra = ""
    if args.reset_every:
        extra += f", reset every {args.reset_every:g} s"
    if args.dt:
        extra += f", dt {args.dt:g} s"
    count = len(out["trajectories"])
    print(
        f"rollout error ({args.horizon:g} s{extra}): {fmt(out['rollout_error_mean'])} ± "
        f"{fmt(out['rollout_error_std'])} over {count} trajector{'y' if count == 1 else 'ies'}"
        f"{ran_away_text(res)}"
    )
    if out["plot"]:
        print(f"plot: {out['plot']}")
    return 0

