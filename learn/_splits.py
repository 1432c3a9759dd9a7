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


#: the default rule's share of the training trajectories held out for validation, and the
#: fewest training trajectories it holds any out of
VALIDATION_SHARE = 0.2
VALIDATION_MIN_TRAIN = 3
#: the note of a run whose model is chosen on its test trajectories
NO_VALIDATION_NOTE = "model chosen on the test trajectories (too few to hold out validation)"


def default_validation(data: Dataset) -> str | int:
    """What ``validation=None`` means for ``data``: the default rule ("auto") for recorded
    data (a file of ``softpinn import``, ``meta["source"] == "import"``), none (0: the test
    loss chooses the model, as before issue 43) for a simulated file, whose spec's split and
    the paper tasks' numbers stay as they were."""
    meta = data.meta if isinstance(data.meta, dict) else {}
    return "auto" if meta.get("source") == "import" else 0


def validation_split(
    data: Dataset,
    train_ids: np.ndarray,
    validation: str | int | float | list[int] | tuple[int, ...] | None,
    *,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Hold out validation trajectories from the training ones, BY TRAJECTORY:
    (train, validation, note). The validation loss then picks the best epoch and decides
    patience, overfit and the target loss; the test trajectories are only scored.

    ``validation``: 0 (none); an int count; a float fraction in (0, 1); ids (each a training
    trajectory); "auto", the default rule: max(1, round(20%)) of the training trajectories
    when they number at least 3, drawn with ``seed``, else none with a note; None: "auto" for
    recorded data, 0 for simulated (:func:`default_validation`). ``note``: one line where
    "auto" holds out nothing, else None. Errors name ``--validation``.
    """
    train_ids = np.asarray(train_ids, dtype=np.int64)
    none = np.zeros(0, dtype=np.int64)
    if validation is None:
        validation = default_validation(data)
    k = len(train_ids)
    if isinstance(validation, str):
        if validation != "auto":
            raise UserError(f"--validation: expected 'auto', a count, a fraction or "
                            f"trajectory ids, got {validation!r}")
        if k < VALIDATION_MIN_TRAIN:
            return train_ids, none, NO_VALIDATION_NOTE
        count = max(1, int(round(VALIDATION_SHARE * k)))
    elif isinstance(validation, (list, tuple, np.ndarray)):
        chosen = np.array(sorted({int(i) for i in validation}), dtype=np.int64)
        outside = np.setdiff1d(chosen, train_ids)
        if outside.size:
            raise UserError(f"--validation: trajectories {outside.tolist()} are not training "
                            f"trajectories of {data.path} (training: {train_ids.tolist()})")
        if chosen.size >= k:
            raise UserError(f"--validation: trajectories {chosen.tolist()} leave no training "
                            f"trajectory of {data.path}")
        return np.setdiff1d(train_ids, chosen), chosen, None
    elif isinstance(validation, float):
        if not 0.0 < validation < 1.0:
            raise UserError(f"--validation: a fraction must be in (0, 1), got {validation}")
        count = max(1, int(round(validation * k)))
    else:
        count = int(validation)
        if count == 0:
            return train_ids, none, None
    if not 1 <= count < k:
        raise UserError(f"--validation: {count} validation trajectories leave none of the "
                        f"{k} training trajectories of {data.path} to train on (at most "
                        f"{max(k - 1, 0)})")
    rng = np.random.default_rng(seed)
    chosen = np.sort(rng.choice(train_ids, size=count, replace=False))
    return np.setdiff1d(train_ids, chosen), chosen, None


def check_validation_setting(v):
    """``TrainConfig.validation``'s type (its fit to the data: :func:`validation_split`); a list
    becomes a tuple."""
    if isinstance(v, list):
        v = tuple(v)
    ok = (v is None or v == "auto"
          or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)
          or (isinstance(v, float) and 0.0 < v < 1.0)
          or (isinstance(v, tuple) and len(v) > 0 and all(
              isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in v)))
    if not ok:
        raise UserError(f"validation: expected 'auto', a count >= 0, a fraction in (0, 1) "
                        f"or trajectory ids (--validation), got {v!r}")
    return v
