"""What ``softpinn train`` and ``softpinn predict`` tell the user about a run beside their
numbers: which trajectories were held out, which rollouts ran away, an interrupted training,
the ensemble member used."""

from __future__ import annotations

import sys
from pathlib import Path

from softpinn.learn import Stop, StopReason, read_json, recorded_test_split


def member_notes(run_dir, run, member) -> list[str]:
    """Which member of an ensemble run the command used, and how it was chosen."""

    try:
        info = read_json(Path(run_dir) / "config.json")
    except Exception:  # noqa: BLE001 - a member folder or no config: one model
        return []
    seeds = info.get("seeds") if isinstance(info, dict) and "members" in info else None
    if not seeds:
        return []
    chosen_on = "validation" if (info.get("split") or {}).get("validation") else "test"
    how = "given by --member" if member is not None else \
        f"the best {chosen_on} loss; --member SEED chooses another"
    return [f"{run_dir} is an ensemble of {len(seeds)} seeds; this is seed {run.seed} ({how})"]


def note_interrupted(run_dir) -> None:
    """A note on stderr where the run's training was interrupted: its model is the best so far,
    not a finished run's."""

    try:
        metrics = read_json(Path(run_dir) / "metrics.json")
    except Exception:  # noqa: BLE001 - no metrics: nothing to say
        return
    stops = [Stop.read(m) for m in metrics.get("members", [metrics]) if isinstance(m, dict)]
    cut = [s.detail for s in stops if s.reason is StopReason.INTERRUPTED]
    if cut:
        print(f"softpinn: note: the training of {run_dir} was {cut[0].split(' (')[0]}: its "
              "model is the best so far (train --resume finishes it)", file=sys.stderr)


def ran_away_text(res) -> str:
    """'; 1 of 4 ran away (trajectory 11, at t = 15.3 s), the other 3: 0.016 ± 0.009', or ''."""
    import numpy as np

    errors = np.asarray(res.rollout_errors, float)
    bad = ~np.isfinite(errors)
    if not bad.any():
        return ""
    where = []
    for i in np.flatnonzero(bad):
        roll = res.rollouts[i]
        q = np.asarray(roll["q_pred"], float)
        rows = np.flatnonzero(~np.isfinite(q).reshape(len(q), -1).all(axis=1))
        when = f", at t = {float(np.asarray(roll['t'])[rows[0]]):.3g} s" if rows.size else ""
        where.append(f"trajectory {res.trajectories[i]}{when}")
    text = f"; {int(bad.sum())} of {len(errors)} ran away ({'; '.join(where[:3])}"
    text += f"; {len(where) - 3} more)" if len(where) > 3 else ")"
    good = errors[~bad]
    if good.size:
        text += f", the other {good.size}: {good.mean():.4e} ± {good.std():.3e}"
    return text


def held_out_text(run_dir, config, data) -> str:
    """Which trajectories the test loss was measured on, and where that split came from."""

    split = read_json(Path(run_dir) / "config.json")["split"]
    test = split["test"]
    if test == split["train"]:
        return ("held out: nothing (the file has one trajectory: the test loss is measured on "
                "the training trajectory)")
    given = config.test_trajectories
    if isinstance(given, tuple):
        source = "given"
    elif given is None and recorded_test_split(data) == test:
        source = "the test split the file records"
    else:
        source = f"drawn at random, --split-seed {config.split_seed}"
    ids = ", ".join(map(str, test))
    return f"held out: trajector{'y' if len(test) == 1 else 'ies'} {ids} ({source})"
