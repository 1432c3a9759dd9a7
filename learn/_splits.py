"""The train/test split of a data set's trajectories (by trajectory, never by sample): a list
the user gives, the split the file records, or a seeded random draw."""

from __future__ import annotations

import numpy as np

from softpinn.errors import UserError
from softpinn.learn._data import Dataset


def recorded_test_split(data: Dataset) -> list[int] | None:
    """The test trajectories the file records (``meta["splits"]["test"]``: the spec's
    ``test_trajectories`` of a simulated file, ``import --test-trajectories K``), or None where
    it records none, or a split that holds out no trajectory or every one, or ids not in the
    file."""
    splits = data.meta.get("splits") if isinstance(data.meta, dict) else None
    test = splits.get("test") if isinstance(splits, dict) else None
    if not isinstance(test, (list, tuple)) or not test:
        return None
    try:
        chosen = sorted({int(i) for i in test})
    except (TypeError, ValueError):
        return None
    ids = set(data.trajectory_ids.tolist())
    if not set(chosen) <= ids or len(chosen) >= len(ids):
        return None
    return chosen


def split_trajectories(
    data: Dataset,
    *,
    test: int | float | list[int] | tuple[int, ...] | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Split trajectory ids into (train, test) BY TRAJECTORY, never by sample.

    ``test``: explicit list of trajectory ids; an int count of test trajectories; a float fraction
    in (0, 1); or None: the test split the file records (``meta["splits"]["test"]``, written by
    ``simulate`` and ``import``) where it has one that leaves a trajectory for training, else 20%
    (at least one). Counts and fractions draw the test trajectories at random with ``seed``.
    With a single trajectory there is nothing to hold out: train and test are both that
    trajectory (reported as such by the caller).
    """
    ids = data.trajectory_ids
    k = len(ids)
    if test is None:
        test = recorded_test_split(data)
    if isinstance(test, (list, tuple, np.ndarray)):
        chosen = np.array(sorted({int(i) for i in test}), dtype=np.int64)
        unknown = np.setdiff1d(chosen, ids)
        if unknown.size:
            raise UserError(
                f"test trajectories {unknown.tolist()} are not in {data.path} "
                f"(trajectory ids {ids.min()}..{ids.max()})"
            )
        if chosen.size >= k:
            raise UserError(
                f"test trajectories {chosen.tolist()} leave no trajectory of {data.path} "
                "for training"
            )
        train_ids = np.setdiff1d(ids, chosen)
        return train_ids, chosen
    if k == 1:
        return ids.copy(), ids.copy()
    if test is None:
        count = max(1, int(round(0.2 * k)))
    elif isinstance(test, float):
        if not 0.0 < test < 1.0:
            raise UserError(f"test fraction must be in (0, 1), got {test}")
        count = max(1, int(round(test * k)))
    else:
        count = int(test)
    if not 1 <= count < k:
        raise UserError(
            f"number of test trajectories must be between 1 and {k - 1} for {data.path} "
            f"({k} trajectories), got {count}"
        )
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(ids, size=count, replace=False))
    return np.setdiff1d(ids, chosen), chosen
