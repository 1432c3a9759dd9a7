"""Trajectories as plain float64 arrays (t, q, q̇, q̈, u per trajectory) for the closed-form
baselines and their rollout errors, from a dataset file's split or from dicts."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from softpinn.errors import UserError
from softpinn.learn._data import Dataset
from softpinn.learn._splits import split_trajectories

__all__ = ["trajectory_arrays"]


def trajectory_arrays(source, traj_ids=None, *, need=("t", "q", "u")) -> list[dict]:
    """Trajectories as dicts of float64 arrays t (T,), q, qd, qdd (T, n), u (T, m), id, from a
    :class:`Dataset` (``traj_ids``; None: the training trajectories of the split ``train``
    uses by default) or from dicts (``learn.trajectories``'s: ``x`` = (q, q̇) gives qd)."""
    if isinstance(source, Dataset):
        ids = split_trajectories(source)[0] if traj_ids is None else traj_ids
        out = []
        for tid in np.asarray(ids).tolist():
            rows = source.indices(int(tid))
            if rows.size == 0:
                raise UserError(f"trajectory {tid} is not in {source.path}")
            out.append({"id": int(tid), "t": source.t[rows], "q": source.q[rows],
                        "qd": source.qd[rows], "qdd": source.qdd[rows], "u": source.u[rows]})
        return out
    if isinstance(source, Mapping):
        source = [source]
    out = []
    for i, tr in enumerate(source):
        d = {"id": int(tr.get("id", i))}
        for key in ("t", "q", "qd", "qdd", "u"):
            if key in tr:
                d[key] = np.asarray(tr[key], dtype=np.float64)
        if "qd" not in d and "x" in tr and "q" in d:
            d["qd"] = np.asarray(tr["x"], dtype=np.float64)[:, d["q"].shape[1]:2 * d["q"].shape[1]]
        missing = [k for k in need if k not in d]
        if missing:
            raise UserError(f"trajectory {d['id']}: missing {', '.join(missing)}")
        out.append(d)
    if not out:
        raise UserError("baselines need at least one trajectory")
    n, m = out[0]["q"].shape[1], out[0]["u"].shape[1]
    for d in out:
        T = d["t"].shape[0]
        if d["q"].shape != (T, n) or d["u"].shape != (T, m) or any(
                d[k].shape != (T, n) for k in ("qd", "qdd") if k in d):
            raise UserError(f"trajectory {d['id']}: needs q, qd, qdd ({T}, {n}) and u ({T}, {m})"
                            f" like the first, got q {d['q'].shape}, u {d['u'].shape}")
    return out
