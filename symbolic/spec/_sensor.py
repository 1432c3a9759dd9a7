"""A simulated sensor on the arm: the spec's ``[sensor]`` table (``docs/experiment.md``).

The paper's experiment (Section V) measured a one-segment spatial arm with an IMU on its tip
plate: tip orientation at a low rate, with noise and an angle that wandered irregularly. A
``[sensor]`` table describes such a sensor, and :func:`record` turns simulated trajectories into
what it would have recorded, the recordings ``softpinn import`` reads (:func:`write_csv`):

    [sensor]
    kind = "imu"               # the only kind: tip orientation of a one-segment spatial PCC arm
    rate_hz = 5.0              # samples per second
    noise_std = 0.01           # white noise on each angle [rad] (one number, or roll, pitch, yaw)
    bias_walk_std = 0.004      # random-walk bias [rad / sqrt(s)] (one number, or three)
    output = "rpy"             # "rpy" (roll, pitch, yaw) or "quaternion" (qw, qx, qy, qz)
    seed = 0

The model of the measurement, per trajectory: the true tip rotation R(t) from the bending
coordinates by the project's forward kinematics (eq. 13, :mod:`symbolic.spec._orientation`) at the
sensor's sample times t_k = t_0 + k / rate_hz (cubic Hermite interpolation of q with q̇ as slopes
between simulated samples, exact on them); its roll, pitch and yaw (R = Rz(yaw) Ry(pitch)
Rx(roll), tip frame to base frame) plus a bias b_k and white noise n_k, per angle:

    b_0 = 0,  b_k = b_{k-1} + bias_walk_std sqrt(t_k - t_{k-1}) xi_k,  n_k = noise_std nu_k,

xi, nu independent standard normal draws (the bias is zero when a recording starts, as after
zeroing the IMU, and drifts as a random walk). The inputs are recorded at the same times as
commanded (linear interpolation between simulated samples, exact on them); the stretch dL does not
turn the tip and is not measured. Trajectory k draws from ``numpy.random.default_rng([seed, k,
round(rate_hz * 1000)])``: reproducible by seed, trajectory k the same whatever the count, and
each rate its own draws.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic._outputs import count_of
from softpinn.symbolic.spec import _orientation as orientation

KINDS = ("imu",)
OUTPUTS = ("rpy", "quaternion")

#: key -> description (docs/experiment.md shows this table)
SENSOR_KEYS: dict[str, str] = {
    "kind": 'what is measured: "imu" (tip orientation of a one-segment spatial PCC arm)',
    "rate_hz": "samples per second [Hz]",
    "noise_std": "standard deviation of the white noise on each angle [rad]: one number, or "
                 "[roll, pitch, yaw]",
    "bias_walk_std": "random-walk bias on each angle [rad/sqrt(s)]: one number, or [roll, pitch, "
                     "yaw]; the bias starts at 0 in every recording",
    "output": '"rpy" (roll, pitch, yaw columns) or "quaternion" (qw, qx, qy, qz)',
    "seed": "random seed (trajectory k draws from default_rng([seed, k, round(1000 rate_hz)]))",
}


class SensorError(UserError):
    """Raised with (field, message); when a spec loads, :mod:`symbolic.spec._spec` turns it into a
    SpecError naming the file."""

    def __init__(self, where: str, message: str):
        super().__init__(f"field '{where}': {message}")
        self.where, self.message = where, message


@dataclass(frozen=True)
class SensorConfig:
    """A validated ``[sensor]`` table."""

    rate_hz: float
    kind: str = "imu"
    noise_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_walk_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    output: str = "rpy"
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "rate_hz": self.rate_hz, "noise_std": list(self.noise_std),
                "bias_walk_std": list(self.bias_walk_std), "output": self.output,
                "seed": self.seed}

    def at_rate(self, rate_hz: float) -> SensorConfig:
        """The same sensor sampling at another rate (the rate study of the experiment)."""
        rate = _positive(rate_hz, "sensor.rate_hz")
        return SensorConfig(rate, self.kind, self.noise_std, self.bias_walk_std, self.output,
                            self.seed)


def parse_sensor(raw: Mapping[str, Any], *, kind: str, segments: int) -> SensorConfig | None:
    """Validate a spec's ``[sensor]`` table (None when the spec has none) for a model of
    ``kind`` with ``segments`` segments; raise :class:`SensorError` naming the field."""
    raw = dict(raw)
    if not raw:
        return None
    unknown = sorted(set(raw) - set(SENSOR_KEYS))
    if unknown:
        raise SensorError(f"sensor.{unknown[0]}",
                          f"unknown key (allowed: {', '.join(SENSOR_KEYS)})")
    if "kind" not in raw:
        raise SensorError("sensor.kind", f"missing (one of {', '.join(KINDS)})")
    if raw["kind"] not in KINDS:
        raise SensorError("sensor.kind", f"expected one of {', '.join(KINDS)}, got "
                          f"{raw['kind']!r}")
    if kind != "spatial-pcc" or segments != 1:
        what = f"{kind} with {count_of(segments, 'segment')}" if segments else kind
        raise SensorError("sensor.kind", f"an imu measures the tip orientation, which "
                          f"determines the bending of a one-segment spatial-pcc arm only; this "
                          f"model is {what}")
    if "rate_hz" not in raw:
        raise SensorError("sensor.rate_hz", "missing (samples per second)")
    out: dict[str, Any] = {"rate_hz": _positive(raw["rate_hz"], "sensor.rate_hz")}
    for key in ("noise_std", "bias_walk_std"):
        if key in raw:
            out[key] = _three(raw[key], f"sensor.{key}")
    if "output" in raw:
        if raw["output"] not in OUTPUTS:
            raise SensorError("sensor.output", f"expected one of {', '.join(OUTPUTS)}, got "
                              f"{raw['output']!r}")
        out["output"] = raw["output"]
    if "seed" in raw:
        s = raw["seed"]
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= 2**32 - 1:
            raise SensorError("sensor.seed", f"expected an integer from 0 to 2**32 - 1, got {s!r}")
        out["seed"] = s
    return SensorConfig(kind=raw["kind"], **out)


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SensorError(where, f"expected a number, got {value!r}")
    if not math.isfinite(value):
        raise SensorError(where, f"must be finite, got {value}")
    return float(value)


def _positive(value, where: str) -> float:
    x = _number(value, where)
    if x <= 0:
        raise SensorError(where, f"must be positive, got {value!r}")
    return x


def _three(value, where: str) -> tuple[float, float, float]:
    vals = value if isinstance(value, list) else [value]
    if len(vals) not in (1, 3):
        raise SensorError(where, f"expected one number or three (roll, pitch, yaw), got "
                          f"{value!r}")
    out = [_number(v, where) for v in vals]
    if any(v < 0 for v in out):
        raise SensorError(where, f"must not be negative, got {value!r}")
    return tuple(out * 3 if len(out) == 1 else out)  # type: ignore[return-value]


def sensor_config(spec) -> SensorConfig:
    """The sensor of a :class:`~symbolic.spec._model_spec.ModelSpec` (validated when the spec was
    loaded); a spec without one is refused."""
    cfg = parse_sensor(spec.sensor, kind=spec.kind, segments=len(spec.segments))
    if cfg is None:
        raise UserError(f"{spec.source}: no [sensor] table (docs/experiment.md describes it)")
    return cfg


# --------------------------------------------------------------------------------------------
# Recording


@dataclass
class Recordings:
    """What the sensor recorded, flat over the samples of all trajectories (as a dataset):
    ``t`` (N,), ``u`` (N, m) inputs, ``orientation`` (N, 3) roll, pitch, yaw or (N, 4)
    quaternions, ``traj`` (N,) int64; and, for checking, the truth at the same times:
    ``q_true``, ``qd_true`` (N, n) configurations and velocities, ``angles_true`` and ``bias``
    (N, 3) in roll, pitch, yaw."""

    t: np.ndarray
    u: np.ndarray
    orientation: np.ndarray
    traj: np.ndarray
    q_true: np.ndarray
    qd_true: np.ndarray
    angles_true: np.ndarray
    bias: np.ndarray
    config: SensorConfig

    @property
    def columns(self) -> tuple[str, ...]:
        return ("roll", "pitch", "yaw") if self.config.output == "rpy" else (
            "qw", "qx", "qy", "qz")

    @property
    def angles(self) -> np.ndarray:
        """The measured roll, pitch, yaw (N, 3) (from the quaternions for that output)."""
        if self.config.output == "rpy":
            return self.orientation
        return orientation.matrix_to_rpy(orientation.quaternion_to_matrix(self.orientation))


def sample_times(t: np.ndarray, rate: float) -> np.ndarray:
    """t_0 + k / rate for k = 0, 1, ... while inside [t_0, t_end] (to 1e-9 of a step)."""
    count = int(math.floor((t[-1] - t[0]) * rate + 1e-9)) + 1
    return t[0] + np.arange(count) / rate


def _interpolate(t, y, yd, tn):
    """Cubic Hermite values of y (slopes yd) at times tn inside [t0, t_end]; exact at the
    samples (a time within 1e-9 of a step of a sample takes that sample)."""
    k = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, len(t) - 2)
    h = t[k + 1] - t[k]
    s = (tn - t[k]) / h
    s = np.where(np.abs(s) < 1e-9, 0.0, np.where(np.abs(s - 1) < 1e-9, 1.0, s))[:, None]
    h = h[:, None]
    out = ((2 * s**3 - 3 * s**2 + 1) * y[k] + (s**3 - 2 * s**2 + s) * h * yd[k]
           + (-2 * s**3 + 3 * s**2) * y[k + 1] + (s**3 - s**2) * h * yd[k + 1])
    return out


def record(spec, sensor: SensorConfig, t, q, qd, u, traj, qdd=None) -> Recordings:
    """What ``sensor`` records of simulated trajectories of the one-segment spatial PCC arm
    ``spec`` (a :class:`~symbolic.spec._model_spec.ModelSpec`; flat arrays over samples, as in a
    dataset: ``t`` (N,), ``q``, ``qd`` (N, n), ``u`` (N, m), ``traj`` (N,); ``qdd`` makes the
    true velocities at the sample times cubic too, else they are linear between samples); see
    the module docstring for the model. The trajectories must be sampled at least as finely as
    the sensor (a sensor faster than the simulation would record interpolated values)."""
    if spec.kind != "spatial-pcc" or len(spec.segments) != 1:
        raise SensorError("sensor.kind", "an imu needs a one-segment spatial-pcc model")
    t, q, qd, u, traj = (np.asarray(a) for a in (t, q, qd, u, traj))
    qdd = None if qdd is None else np.asarray(qdd)
    seg = spec.segments[0]
    rate = sensor.rate_hz
    pieces: dict[str, list[np.ndarray]] = {k: [] for k in
                                           ("t", "u", "o", "traj", "q", "v", "a", "b")}
    for k in np.unique(traj).tolist():
        rows = np.flatnonzero(traj == k)
        tk = t[rows]
        if len(tk) < 2:
            raise SensorError("sensor.rate_hz", f"trajectory {k} has fewer than 2 samples")
        step = float(np.min(np.diff(tk)))
        if step > 1.0 / rate * (1 + 1e-9):
            raise SensorError("sensor.rate_hz", f"{rate:g} Hz is faster than the simulated "
                              f"trajectories ({1 / step:.6g} Hz): simulate at the sensor's rate "
                              "or faster")
        ts = sample_times(tk, rate)
        qs = _interpolate(tk, q[rows], qd[rows], ts)
        if qdd is not None:
            vs = _interpolate(tk, qd[rows], qdd[rows], ts)
        else:
            vs = np.stack([np.interp(ts, tk, qd[rows, j]) for j in range(qd.shape[1])], 1)
        us = np.stack([np.interp(ts, tk, u[rows, j]) for j in range(u.shape[1])], 1) \
            if u.shape[1] else np.zeros((len(ts), 0))
        R = orientation.rotation_of_bending(qs[:, :2], spec.parameterization,
                                            seg.actuator_radius)
        angles = orientation.matrix_to_rpy(R)
        rng = np.random.default_rng([sensor.seed, int(k), int(round(rate * 1000))])
        walk = rng.standard_normal((len(ts), 3))
        white = rng.standard_normal((len(ts), 3))
        dt = np.diff(ts, prepend=ts[0])[:, None]
        bias = np.cumsum(np.asarray(sensor.bias_walk_std) * np.sqrt(dt) * walk, axis=0)
        measured = angles + bias + np.asarray(sensor.noise_std) * white
        if sensor.output == "quaternion":
            measured = orientation.matrix_to_quaternion(orientation.rpy_to_matrix(measured))
        for key, value in (("t", ts), ("u", us), ("o", measured), ("q", qs), ("v", vs),
                           ("a", angles), ("b", bias)):
            pieces[key].append(value)
        pieces["traj"].append(np.full(len(ts), k, dtype=np.int64))
    cat = {k: np.concatenate(v) for k, v in pieces.items()}
    return Recordings(t=cat["t"], u=cat["u"], orientation=cat["o"], traj=cat["traj"],
                      q_true=cat["q"], qd_true=cat["v"], angles_true=cat["a"], bias=cat["b"],
                      config=sensor)


def write_csv(path: str | Path, rec: Recordings, trajectories: Sequence[int] | None = None,
              *, comment: str | None = None) -> Path:
    """The recordings as one CSV file ``softpinn import`` reads (``docs/import.md``): columns
    ``traj, t, u0 .. u{m-1}`` and the orientation columns, 17 significant digits."""
    path = Path(path)
    keep = np.ones(len(rec.t), bool) if trajectories is None else np.isin(
        rec.traj, np.asarray(list(trajectories)))
    m = rec.u.shape[1]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        if comment:
            for line in comment.splitlines():
                f.write(f"# {line}\n")
        w = csv.writer(f)
        w.writerow(["traj", "t", *(f"u{j}" for j in range(m)), *rec.columns])
        for i in np.flatnonzero(keep):
            w.writerow([int(rec.traj[i]), repr(float(rec.t[i])),
                        *(repr(float(x)) for x in rec.u[i]),
                        *(repr(float(x)) for x in rec.orientation[i])])
    tmp.replace(path)
    return path
