"""Recorded trajectories -> a dataset file (``docs/import.md``): ``softpinn import``.

:func:`import_recordings` reads CSV files (:mod:`symbolic.recorded._csv`), maps tip orientation to
the bending configuration of a one-segment spatial PCC arm (:mod:`symbolic.spec._orientation`),
smooths and differentiates (:mod:`symbolic.recorded._filters`), optionally resamples to a uniform
rate, computes the momentum p = M(q) q̇ with the model's mass matrix, and returns
:class:`~symbolic.simulation._datafile.DatasetArrays` whose ``meta`` records every choice (and,
where the spec has an ``[actuator]`` table, ``meta["actuator"]``: the lag and delay per input
between the recorded commands u and the arm, which ``softpinn train`` applies).

Order of the steps, per trajectory: orientation -> q (phi unwrapped along time for
``phi-theta``); smooth q (and q̇ when recorded) on the recorded times; velocities and
accelerations from the smoother's derivative, or central differences; then, with ``rate``,
cubic Hermite interpolation to the uniform times (inputs linearly; inputs are never smoothed).
Smoothing before resampling follows the paper (moving average, then resampling to 5 Hz) and
keeps the smoother's window in recorded samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np

from softpinn.symbolic._outputs import count_of
from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.recorded import _filters as filters
from softpinn.symbolic.recorded._csv import (
    ORIENTATION_COLUMNS,
    Recording,
    RecordingError,
    read_recordings,
)
from softpinn.symbolic.simulation._datafile import FORMAT, FORMAT_VERSION, DatasetArrays
from softpinn.symbolic.spec import _orientation as orientation
from softpinn.symbolic.spec._model_spec import ModelSpec
from softpinn.symbolic.spec._spec import load_spec

CONVENTIONS = {
    "quaternion": "unit quaternion (qw, qx, qy, qz), Hamilton, rotating tip-frame vectors into "
    "the arm's base frame (identity for the straight arm, tip z along the tangent)",
    "rpy": "roll, pitch, yaw [rad], R = Rz(yaw) Ry(pitch) Rx(roll), tip frame -> base frame "
    "(all zero for the straight arm, tip z along the tangent)",
}
#: a mean twist about the tangent above this [rad] gets a note (the sensor frame looks turned)
TWIST_NOTE = 0.05


@dataclass
class ImportResult:
    """The dataset and the notes worth telling the user (also in ``meta['import']['notes']``)."""

    data: DatasetArrays
    notes: list[str] = field(default_factory=list)


def _orientation_model(spec: ModelSpec, kind: str) -> None:
    if spec.kind != "spatial-pcc" or len(spec.segments) != 1:
        what = (f"{spec.kind} with {count_of(len(spec.segments), 'segment')}" if spec.segments
                else spec.kind)
        raise RecordingError(
            f"orientation: --orientation {kind} needs a one-segment spatial-pcc model (the tip "
            f"rotation determines the bending of one segment only); model {spec.name} is {what}"
        )


def configurations_from_orientation(spec: ModelSpec, rec: Recording, kind: str):
    """q (N, 3) of a one-segment spatial PCC arm from a recording's orientation columns, the
    stretch set to 0 (not observable); returns ``(q, twist)``."""
    _orientation_model(spec, kind)
    o = rec.orientation
    R = orientation.quaternion_to_matrix(o) if kind == "quaternion" else \
        orientation.rpy_to_matrix(o)
    seg = spec.segments[0]
    bend, theta, twist = orientation.bending_from_rotation(R, spec.parameterization,
                                                           seg.actuator_radius)
    bad = np.flatnonzero(theta > orientation.THETA_MAX)
    if bad.size:
        col = ORIENTATION_COLUMNS[kind][0]
        raise RecordingError(
            f"{rec.file}, line {int(rec.lines[bad[0]])}, column '{col}': the tip is bent by "
            f"180 degrees (theta = {theta[bad[0]]:.6f} rad): orientation cannot tell the "
            "bending direction there"
        )
    if spec.parameterization == "phi-theta":
        bend[:, 0] = np.unwrap(bend[:, 0])
    q = np.zeros((len(rec.t), 3))
    q[:, :2] = bend
    return q, twist


def _unit_notes(spec, recs, files) -> list[str]:
    """Notes on what looks like a mistake the data cannot refuse: the same file twice, times in
    milliseconds, angles in degrees."""
    notes = []
    seen: dict[str, str] = {}
    for f in files:
        if f.sha256 in seen:
            notes.append(f"{f.path} is the same recording as {seen[f.sha256]} (equal sha256): "
                         "its trajectories appear twice")
        seen.setdefault(f.sha256, f.path)
    steps = np.concatenate([np.diff(r.t) for r in recs])
    if len(steps) and float(np.median(steps)) > 1.0:
        notes.append(f"the recordings' times step by {float(np.median(steps)):.4g} (median): "
                     "softpinn reads t in seconds; if yours are milliseconds, divide t by 1000")
    for j, name in enumerate(spec.coordinate_names):
        if name.rstrip("0123456789") in ("theta", "phi") and not any(r.q is None for r in recs):
            top = max(float(np.max(np.abs(r.q[:, j]))) for r in recs)
            if top > 2 * np.pi:
                notes.append(f"{name} reaches {top:.4g}: softpinn reads angles in radians; if "
                             "these are degrees, multiply by pi / 180")
    return notes


def import_recordings(
    paths: Sequence[str | Path],
    model: str | Path | ModelSpec,
    *,
    orientation_kind: str | None = None,
    smooth: str | filters.Smoother = "none",
    rate: float | None = None,
    test_trajectories: int = 0,
    differences: int | None = None,
    observed_only: bool = False,
) -> ImportResult:
    """Turn recordings into a dataset for ``model`` (a preset name, spec path or ModelSpec).

    ``orientation_kind``: None (the files hold ``q0 ..``), ``"quaternion"`` or ``"rpy"``;
    ``smooth``: a :func:`symbolic.recorded._filters.parse_smoother` text; ``rate``: resample every
    trajectory to this uniform rate [Hz]; ``test_trajectories``: the last K trajectories form
    the test split (``meta['splits']``); ``differences``: the order (2 or 4) of the central
    differences where the smoother has no derivative of its own (none, movmean); None keeps a
    given Smoother's, 2 for a text. ``observed_only``: leave out the coordinates the
    recordings cannot determine (a tip orientation's stretch, otherwise set to 0), so that a
    network learns only what was measured (issue 43: the networks moved an unmeasured stretch).
    """
    spec = load_spec(model)
    sm = filters.parse_smoother(smooth, differences)
    n, m = spec.n, spec.m
    if orientation_kind is not None:
        _orientation_model(spec, orientation_kind)
    if rate is not None and not (np.isfinite(rate) and rate > 0):
        raise RecordingError(f"rate: must be a positive number of Hz, got {rate}")
    recs, files = read_recordings(paths, n=n, m=m, model=spec.name, orientation=orientation_kind)
    K = len(recs)
    if isinstance(test_trajectories, bool) or not 0 <= test_trajectories < K:
        raise RecordingError(f"test_trajectories: must be in 0 .. {K - 1} (the files hold {K} "
                             f"trajectories), got {test_trajectories}")
    notes: list[str] = []
    twists = []
    pieces = {k: [] for k in ("t", "q", "qd", "qdd", "u", "traj")}
    sources = []
    for k, rec in enumerate(recs):
        if len(rec.t) < max(2, sm.min_samples):
            raise RecordingError(f"{rec.where}: {count_of(len(rec.t), 'sample')}; smoothing "
                                 f"{sm.label} needs at least {max(2, sm.min_samples)} per "
                                 "trajectory")
        if orientation_kind is not None:
            q_raw, twist = configurations_from_orientation(spec, rec, orientation_kind)
            twists.append(twist)
        else:
            q_raw = rec.q
        q, qd, qdd = filters.smooth(rec.t, q_raw, sm)
        if rec.qd is not None:
            qd, qdd, _ = filters.smooth(rec.t, rec.qd, sm)
        t, u = rec.t, rec.u
        if rate is not None:
            t, q, qd, qdd = filters.resample_uniform(rec.t, q, qd, qdd, rate)
            if len(t) < 2:
                raise RecordingError(f"{rec.where}: lasts {rec.t[-1] - rec.t[0]:g} s, less than "
                                     f"one step at --rate {rate:g} Hz")
            u = np.stack([np.interp(t, rec.t, rec.u[:, j]) for j in range(m)], 1) if m else \
                np.zeros((len(t), 0))
        for key, value in (("t", t), ("q", q), ("qd", qd), ("qdd", qdd), ("u", u)):
            pieces[key].append(value)
        pieces["traj"].append(np.full(len(t), k, dtype=np.int64))
        sources.append({"file": rec.file, "traj": rec.traj,
                        "lines": [int(rec.lines[0]), int(rec.lines[-1])],
                        "recorded_samples": len(rec.t), "samples": len(t)})
    arrays = {k: np.concatenate(v) for k, v in pieces.items()}
    unobserved = []
    if orientation_kind is not None:
        unobserved = [spec.coordinate_names[2]]
        notes.append(
            f"orientation determines the bending ({', '.join(spec.coordinate_names[:2])}) only: "
            f"the stretch {unobserved[0]} is not observable and is set to 0 (with its "
            "derivatives); the data describe the bending of the arm at its rest length"
        )
        mean_twist = float(np.mean(np.abs(np.concatenate(twists))))
        if mean_twist > TWIST_NOTE:
            notes.append(
                f"the orientation turns about the tip tangent by {mean_twist:.3g} rad on "
                "average, which constant curvature does not allow: check that the sensor's frame "
                "is the tip frame (z along the tangent, identity when straight)"
            )
    arrays["p"] = momentum(spec, arrays["q"], arrays["qd"])
    counts = [s["samples"] for s in sources]
    steps = np.concatenate([np.diff(t) for t in pieces["t"]])
    uniform = rate is not None or (len(steps) and np.allclose(steps, steps.mean(), rtol=1e-9,
                                                             atol=0))
    out_rate = float(rate) if rate is not None else (float(1 / steps.mean()) if uniform else None)
    if rate is not None:
        raw = np.concatenate([np.diff(r.t) for r in recs])
        raw_rate = 1 / float(np.median(raw))
        if rate > raw_rate * (1 + 1e-9):
            notes.append(f"--rate {rate:g} Hz is above the recordings' {raw_rate:.4g} Hz: the "
                         "extra samples are interpolated, not measured")
    notes += _unit_notes(spec, recs, files)
    ids = list(range(K))
    ntest = int(test_trajectories)
    splits = {"train": ids[: K - ntest], "test": ids[K - ntest :],
              "blackbox_train": ids[: K - ntest]}
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "source": "import",
        "spec": spec.to_dict(),
        "n": n,
        "m": m,
        "coordinates": list(spec.coordinate_names),
        "rate": out_rate,
        "trajectories": K,
        "samples_per_trajectory": counts[0] if len(set(counts)) == 1 else None,
        "splits": splits,
        "import": {
            "files": [{"path": f.path, "sha256": f.sha256, "rows": len(f.rows),
                       "ignored_columns": f.ignored} for f in files],
            "trajectories": sources,
            "state": "orientation" if orientation_kind else "configurations",
            "orientation": orientation_kind,
            "orientation_convention": CONVENTIONS.get(orientation_kind),
            "orientation_map": (
                "eq. 13: theta and phi from the tip tangent (third column of R); delta: "
                "(dx, dy) = d theta / sin(theta) (R02, R12)" if orientation_kind else None
            ),
            "unobserved": unobserved,
            "max_twist_rad": float(np.max(np.abs(np.concatenate(twists)))) if twists else None,
            "smooth": sm.describe(),
            "velocities": (
                "the qd columns, smoothed" if any(r.qd is not None for r in recs)
                else sm.describe()["derivatives"] + " of the smoothed q"
            ),
            "accelerations": sm.describe()["derivatives"] + " of the smoothed velocities",
            "resample": None if rate is None else {
                "rate": float(rate),
                "method": "cubic Hermite interpolation of q and qd (slopes qd and qdd), qdd "
                          "linear; after smoothing",
            },
            "inputs": "as recorded, not smoothed" + ("; linear interpolation" if rate else ""),
            "momentum": "p = M(q) qd with the spec's mass matrix (computed, not measured)",
            "test_trajectories": ntest,
            "notes": notes,
        },
        "package_version": _version("softpinn"),
        "numpy_version": np.__version__,
    }
    if spec.actuator:
        meta["actuator"] = spec.actuator_meta()
    if observed_only and unobserved:
        arrays, meta = _observed(spec, arrays, meta, unobserved)
        notes[0] = (f"orientation determines the bending ({', '.join(meta['coordinates'])}) "
                    f"only: --observed-only leaves out the stretch {', '.join(unobserved)}, "
                    "which it cannot see")
        meta["import"]["notes"] = notes
    return ImportResult(DatasetArrays(meta=meta, **arrays), notes)


def _observed(spec: ModelSpec, arrays: dict, meta: dict, unobserved: list[str]):
    """``arrays`` and ``meta`` without the ``unobserved`` coordinates. p keeps its observed
    rows: with the unobserved velocities 0 they are M_oo q̇_o (the observed block of eq. 7's
    p = M q̇)."""
    keep = [i for i, name in enumerate(spec.coordinate_names) if name not in unobserved]
    out = {k: (v[:, keep].copy() if k in ("q", "qd", "qdd", "p") else v)
           for k, v in arrays.items()}
    names = [spec.coordinate_names[i] for i in keep]
    meta = {**meta, "n": len(keep), "coordinates": names,
            "import": {**meta["import"], "dropped": list(unobserved)}}
    return out, meta


def momentum(spec: ModelSpec, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """p = M(q) qd for every sample (the model's mass matrix)."""
    tm = TrueModel(spec, compiled=False)
    out = np.empty_like(qd)
    chunk = 20000
    for a in range(0, len(q), chunk):
        out[a : a + chunk] = tm.momentum(q[a : a + chunk], qd[a : a + chunk])
    return out


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None
