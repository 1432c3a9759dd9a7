"""The dataset file (``docs/dataset.md``): :class:`DatasetArrays`, written atomically by
:func:`write_dataset` (temporary file, then :func:`os.replace`) and read back with numpy alone
by :func:`read_dataset`; selecting trajectories, resampling and splitting.

Flat arrays over all samples of all trajectories: ``t`` (T,), ``q``, ``qd``, ``qdd``, ``p``
(T, n), ``u`` (T, m), ``traj`` (T,) int64, and ``meta``, a 0-d string of JSON (the spec, how the
data were simulated, signals, seeds, noise, splits, versions). ``p`` may be left out (a recording
has no momenta; ``softpinn.files.DATASET_OPTIONAL``, the rule ``learn`` reads files by too: then
``DatasetArrays.p`` is None). Optional: static equilibria
(:mod:`symbolic.simulation._equilibria`) ``eq_q`` (K, n), ``eq_u`` (K, m), ``eq_force`` (K, n),
kept through selection, resampling and splitting (they are labels of the model, not samples).
"""


from __future__ import annotations

import json
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softpinn.files import (
    DATASET_ARRAYS,
    DATASET_EQUILIBRIUM,
    DATASET_REQUIRED,
)
from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.simulation._datatable import DataError
from softpinn.symbolic.simulation._signals import Signal, signal_from_dict

FORMAT = "softpinn-dataset"
FORMAT_VERSION = 1
#: The arrays of a dataset file but ``meta``, in the order they are written (``p`` optional:
#: :data:`softpinn.files.DATASET_OPTIONAL`).
ARRAY_KEYS = DATASET_ARRAYS
#: Optional arrays: static equilibria G(q*) = A(q*) u* and their force f* = G(q*) (docs/dataset.md).
EQUILIBRIUM_KEYS = DATASET_EQUILIBRIUM

# --------------------------------------------------------------------------------------------
# Arrays


@dataclass
class DatasetArrays:
    """The arrays and meta of a dataset file (flat over samples, see the module docstring)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    p: np.ndarray | None  # None: a file without momenta (written by simulate: always there)
    u: np.ndarray
    traj: np.ndarray
    meta: dict
    eq_q: np.ndarray | None = None
    eq_u: np.ndarray | None = None
    eq_force: np.ndarray | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays a file holds: :data:`ARRAY_KEYS` (those present) and the equilibria when
        present."""
        out = {k: getattr(self, k) for k in ARRAY_KEYS if getattr(self, k) is not None}
        out.update(self.equilibria())
        return out

    def rows(self, rows) -> dict[str, np.ndarray | None]:
        """The samples ``rows`` (indices or a slice) of every array of :data:`ARRAY_KEYS` (an
        absent one stays None)."""
        return {k: None if getattr(self, k) is None else getattr(self, k)[rows]
                for k in ARRAY_KEYS}

    def equilibria(self) -> dict[str, np.ndarray]:
        """The optional equilibrium arrays that are present (none, or all three)."""
        return {k: getattr(self, k) for k in EQUILIBRIUM_KEYS if getattr(self, k) is not None}

    @property
    def trajectory_ids(self) -> np.ndarray:
        return np.unique(self.traj)

    def __len__(self) -> int:
        return len(self.t)


# --------------------------------------------------------------------------------------------
# Files


def write_dataset(path: str | os.PathLike, data: DatasetArrays, *, force: bool = False) -> Path:
    """Write ``data`` to ``path`` (``.npz``) atomically; refuse to overwrite without ``force``."""
    return write_datasets([(path, data)], force=force)[0]


def write_datasets(
    items: Sequence[tuple[str | os.PathLike, DatasetArrays]], *, force: bool = False
) -> list[Path]:
    """Write several dataset files (a data set and its resampled siblings) as one step.

    Every file is first written to a temporary sibling (``.<name>.partial-<pid>@<host>-*``), and
    only when all are complete are they renamed into place (the first path last), so that an
    interrupted call leaves none of them and nothing that blocks a rerun; temporary siblings of
    a killed run are removed. Without ``force`` an existing file is refused before anything is
    written. The meta must be strict JSON (no NaN or infinity). The files are claimed while
    they are written (:func:`symbolic._outputs.claimed`): one writer at a time.
    """
    paths = [Path(p) for p, _ in items]
    with outputs.claimed(paths, "write_dataset"):
        return _write_datasets(paths, items, force=force)


def _write_datasets(paths: list[Path], items, *, force: bool) -> list[Path]:
    for path in paths:
        if path.suffix != ".npz":
            raise DataError(f"--out {path}: a dataset file must end in .npz")
        if path.is_dir():
            raise DataError(f"--out {path}: is a folder, not a dataset file")
        if path.exists() and not force:
            raise DataError(f"--out {path}: file exists (use --force to overwrite)")
    metas = [outputs.dumps(data.meta, what=f"dataset meta of {path}") for path, (_, data)
             in zip(paths, items, strict=True)]
    tmps: list[Path] = []
    try:
        for path, (_, data), meta in zip(paths, items, metas, strict=True):
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                outputs.remove_stale_partials(path)
                tmp = outputs.partial_path(path)
                tmps.append(tmp)
                with open(tmp, "wb") as fh:
                    np.savez(
                        fh,
                        **{k: np.ascontiguousarray(v) for k, v in data.arrays().items()},
                        meta=np.array(meta),
                    )
            except OSError as exc:
                raise outputs.cannot_write("--out", path, exc) from None
        for tmp, path in reversed(list(zip(tmps, paths, strict=True))):
            try:
                outputs.install_file(tmp, path)
            except OSError as exc:
                raise outputs.cannot_write("--out", path, exc) from None
    finally:
        for tmp in tmps:
            outputs.remove_path(tmp)
    return paths


def read_dataset(path: str | os.PathLike) -> DatasetArrays:
    """Read a dataset file (numpy only; the learning side has its own validating loader)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"dataset file {path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):  # a plain .npy array, not a dataset's .npz
                raise ValueError("a single array, not an .npz archive")
            missing = [k for k in DATASET_REQUIRED if k not in z.files]
            if missing:
                raise DataError(f"dataset file {path}: missing key(s) {', '.join(missing)}")
            arrays = {k: np.asarray(z[k]) if k in z.files else None for k in ARRAY_KEYS}
            arrays.update({k: np.asarray(z[k]) for k in EQUILIBRIUM_KEYS if k in z.files})
            meta = json.loads(str(z["meta"].item()))
    except DataError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"dataset file {path}: cannot be read as a data set ({first})") from None
    return DatasetArrays(meta=meta, **arrays)



# --------------------------------------------------------------------------------------------
# Resampling and splitting


def select_trajectories(
    data: DatasetArrays, ids: Sequence[int], *, renumber: bool = False
) -> DatasetArrays:
    """The samples of the trajectories ``ids`` (in that order); meta records the selection."""
    ids = [int(i) for i in ids]
    known = set(data.trajectory_ids.tolist())
    missing = [i for i in ids if i not in known]
    if missing:
        raise DataError(f"trajectories {missing} are not in the data set (it has {sorted(known)})")
    rows = (
        np.concatenate([np.flatnonzero(data.traj == i) for i in ids])
        if ids
        else np.zeros(0, dtype=int)
    )
    out = data.rows(rows)
    if renumber:
        mapping = {old: new for new, old in enumerate(ids)}
        out["traj"] = np.array([mapping[int(i)] for i in out["traj"]], dtype=np.int64)
    meta = dict(data.meta)
    meta["selected_trajectories"] = ids
    if renumber and "signals" in meta:
        meta["signals"] = [data.meta["signals"][i] for i in ids]
        meta["initial_states"] = [data.meta["initial_states"][i] for i in ids]
        meta["trajectories"] = len(ids)
    return DatasetArrays(meta=meta, **out, **data.equilibria())


def resample(data: DatasetArrays, rate: float) -> DatasetArrays:
    """Keep every k-th sample so that the output rate becomes ``rate`` [Hz].

    The data set's rate must be a whole multiple of ``rate`` (the samples are exact states of the
    variable-step solution at the new rate's times, as the paper's 1000/100/50 Hz data).
    """
    src = float(data.meta.get("rate", 0.0))
    if not (rate > 0 and np.isfinite(rate)):
        raise DataError(f"rate: must be positive, got {rate}")
    ratio = src / rate
    if src <= 0 or ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise DataError(f"rate: {rate:g} Hz must divide the data set's rate {src:g} Hz")
    k = int(round(ratio))
    rows = np.concatenate([np.flatnonzero(data.traj == i)[::k] for i in data.trajectory_ids])
    meta = dict(data.meta)
    meta["rate"] = float(rate)
    meta["resampled_from_rate"] = src
    meta["samples_per_trajectory"] = int(len(rows) // max(len(data.trajectory_ids), 1))
    meta["simulation"] = dict(meta.get("simulation", {}), rate=float(rate))
    return DatasetArrays(meta=meta, **data.rows(rows), **data.equilibria())


def split(data: DatasetArrays, name: str) -> DatasetArrays:
    """One of the paper's splits recorded in meta: ``train``, ``test`` or ``blackbox_train``."""
    splits = data.meta.get("splits", {})
    if name not in splits:
        raise DataError(f"split: expected one of {', '.join(splits)}, got {name!r}")
    return select_trajectories(data, splits[name])


def take_samples(data: DatasetArrays, count: int | None) -> DatasetArrays:
    """The first ``count`` samples in file order (whole trajectories first, the last one cut),
    e.g. the paper's ``physics_samples``; None keeps everything."""
    if count is None or count >= len(data):
        return data
    if count < 2:
        raise DataError(f"physics_samples: must be at least 2, got {count}")
    out = data.rows(slice(None, count))
    meta = dict(data.meta, samples_kept=int(count))
    return DatasetArrays(meta=meta, **out, **data.equilibria())


def signals_of(data: DatasetArrays) -> list[Signal]:
    """The input signals recorded in a data set's meta."""
    return [signal_from_dict(d) for d in data.meta.get("signals", [])]
