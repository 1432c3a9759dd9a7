"""A soft arm that is not PCC: a Cosserat rod with a heavy tip, simulated with PyElastica (issue 43,
item 4), recorded as a real arm would be, in the CSV format ``softpinn import`` reads.

The arm is a uniform elastic rod (shearable and extensible, Cosserat theory), clamped at its base,
hanging (gravity along the rod) or upright, with a tip mass that carries rotational inertia, and
linear viscous damping of the nodes' velocities and the elements' angular velocities. Under
gravity and the heavy tip its curvature varies along its length: no PCC segment describes it.

Actuation: four inputs, as the ``experiment`` preset's tendons at 0, 90, 180, 270 degrees. Input
j [N m] is a bending moment at the tip, in the tip's own frame (a follower, as a tendon anchored
at the tip), that bends the arm toward angle 2 pi j / 4 of the base frame: without gravity a
constant net moment M bends the rod into an arc of tip angle M L / (E I) (Euler-Bernoulli). Each
commanded input reaches the rod through a dead time (``delay``) and then a first-order lag
(``tau``): tau y' = u(t - delay) - y, y the applied moment (the actuator's "measured" signal).

Observation: a tip orientation sensor at ``rate_hz``, the rotation from the tip frame (z along the
tangent of the last element) to the base frame (z along the straight arm: down for a hanging arm,
up for an upright one; identity when straight), written as a unit quaternion (qw, qx, qy, qz)
(``docs/import.md``, ``softpinn import --orientation quaternion``), with optional Gaussian noise
(a random rotation vector in the tip frame, ``noise`` rad per axis).

The rod has one extra element inside the clamp (fixed in position and orientation), so that the
free length is ``length``. PyElastica integrates explicitly (position Verlet); ``time_step`` must
resolve the rod's shear and stretch waves (2e-4 s for the defaults; 4e-4 s diverges).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from softpinn.actuator import lag
from softpinn.errors import UserError
from softpinn.symbolic._outputs import dumps, install_file, partial_path, remove_stale_partials
from softpinn.symbolic.spec._orientation import (
    bending_from_rotation,
    matrix_to_quaternion,
    quaternion_to_matrix,
)

#: input j bends the arm toward angle 2 pi j / 4 of the base frame (the experiment's tendons)
INPUTS = 4
ANGLES = 2 * np.pi * np.arange(INPUTS) / INPUTS
SIGNALS = ("multisine", "steps")
SETTINGS_FILE = "cosserat.json"
#: what ``softpinn import`` needs besides the files: a one-segment spatial arm with 4 inputs and
#: d = 1 (so dx, dy are the bending angle's components in rad)
IMPORT_ARGS = ("--model", "experiment", "--orientation", "quaternion")

Command = Callable[[np.ndarray], np.ndarray]
_POSITIVE = ("length", "radius", "density", "youngs_modulus", "time_step", "amplitude",
             "frequency_low", "frequency_high", "hold_low", "hold_high", "ramp")
_NON_NEGATIVE = ("tip_mass", "tip_radius", "gravity", "damping", "rotational_damping", "fade_in",
                 "settle")


@dataclass(frozen=True)
class CosseratArm:
    """The arm, its actuators and the excitation of a recording (SI units)."""

    # the rod
    length: float = 0.3  # free length [m]
    radius: float = 0.015  # [m]
    density: float = 1100.0  # [kg/m^3], silicone
    youngs_modulus: float = 3.0e6  # [Pa]
    poisson_ratio: float = 0.5  # shear modulus E / (2 (1 + nu))
    tip_mass: float = 0.1  # [kg], about half the rod's 0.23 kg
    tip_radius: float = 0.03  # the tip mass is a solid sphere of this radius (its inertia) [m]
    hanging: bool = True  # gravity along the rod (False: the arm stands up against it)
    gravity: float = 9.81  # [m/s^2]
    damping: float = 2.0  # translational velocity decay rate [1/s]
    rotational_damping: float = 2.0  # angular velocity decay rate [1/s]
    n_elements: int = 20  # free elements (one more sits in the clamp)
    time_step: float = 2e-4  # largest integration step [s]; rounded down to divide 1/rate_hz
    # the actuators: a float for all four inputs, or four numbers
    tau: float | tuple[float, ...] = 0.2  # first-order lag [s] (0: none)
    delay: float | tuple[float, ...] = 0.15  # dead time [s]
    # the excitation: every input is amplitude (1 + s(t)), |s| <= 1, so it stays in [0, 2 A]
    # (a tendon pulls only); the net moment on an axis, u0 - u2 or u1 - u3, spans [-2 A, 2 A]
    signal: str = "multisine"  # or "steps": random levels joined by half-cosine ramps
    amplitude: float = 0.25  # A [N m]: hanging, tip bending to 40 degrees (mean 18)
    frequency_low: float = 0.1  # multisine band [Hz]
    frequency_high: float = 2.0
    components: int = 4  # sines per input, frequencies log-uniform in the band
    hold_low: float = 0.5  # steps: each level held for a time uniform in [low, high] [s]
    hold_high: float = 2.0
    ramp: float = 0.2  # steps: duration of a half-cosine transition [s]
    fade_in: float = 1.0  # the multisine grows from 0 over this time [s]
    settle: float = 0.5  # simulated before t = 0 with the inputs at their first value [s]

    def __post_init__(self):
        for name in ("tau", "delay"):
            value = getattr(self, name)
            values = tuple(float(v) for v in np.broadcast_to(np.asarray(value, float), (INPUTS,)))
            if not all(math.isfinite(v) and v >= 0 for v in values):
                raise UserError(f"{name}: expected {INPUTS} numbers >= 0 [s], got {value!r}")
            object.__setattr__(self, name, values)
        for name in _POSITIVE + _NON_NEGATIVE:
            v, strict = getattr(self, name), name in _POSITIVE
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
                    and (v > 0 or not strict)):
                raise UserError(f"{name}: expected a number {'>' if strict else '>='} 0, got {v!r}")
        for name, low in (("n_elements", 4), ("components", 1)):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= low):
                raise UserError(f"{name}: expected an integer >= {low}, got {v!r}")
        if not -1 < self.poisson_ratio <= 0.5:
            raise UserError(f"poisson_ratio: expected a number in (-1, 0.5], got "
                            f"{self.poisson_ratio!r}")
        if self.signal not in SIGNALS:
            raise UserError(f"signal: expected one of {', '.join(SIGNALS)}, got {self.signal!r}")
        if self.frequency_high < self.frequency_low or self.hold_high < self.hold_low:
            raise UserError("frequency_high, hold_high: must not be below frequency_low, hold_low")
        if not self.hanging and self.buckling_load_ratio >= 1:
            raise UserError(
                f"hanging: an upright arm with tip_mass {self.tip_mass} kg buckles under its "
                f"weight ({self.buckling_load_ratio:.2f} of the critical load, Dunkerley): lower "
                "tip_mass or raise youngs_modulus, radius")

    @classmethod
    def upright(cls, **changes) -> CosseratArm:
        """The arm standing up: a lighter tip (0.37 of the buckling load, Dunkerley) and smaller
        moments for the same tens of degrees."""
        return cls(**{"hanging": False, "tip_mass": 0.05, "amplitude": 0.1, **changes})

    @property
    def bending_stiffness(self) -> float:
        """E I [N m^2], I = pi r^4 / 4."""
        return self.youngs_modulus * math.pi * self.radius**4 / 4

    @property
    def buckling_load_ratio(self) -> float:
        """Weight over critical load of the clamped-free column, tip mass and self-weight
        combined (Dunkerley): the tip's Euler load pi^2 E I / (4 L^2), self-weight's 7.84 E I / L^2
        (Greenhill). An upright arm needs a ratio below 1."""
        EI, L, g = self.bending_stiffness, self.length, self.gravity
        rod_mass = self.density * math.pi * self.radius**2 * L
        return (self.tip_mass * g / (math.pi**2 * EI / (4 * L**2))
                + rod_mass * g / (7.837 * EI / L**2))


@dataclass(frozen=True)
class Trajectory:
    """One simulated recording at the sensor's rate."""

    t: np.ndarray  # (N,) [s]
    command: np.ndarray  # (N, 4) commanded inputs [N m]
    actuator: np.ndarray  # (N, 4) applied moments: delayed and lagged [N m]
    rotation: np.ndarray  # (N, 3, 3) tip -> base, without noise
    quaternion: np.ndarray  # (N, 4) the sensor's reading (w, x, y, z), noise included
    tip: np.ndarray  # (N, 3) tip position in the base frame [m]

    def bending(self) -> np.ndarray:
        """(N, 2) the (dx, dy) ``softpinn import`` gives without noise for d = 1 [rad]."""
        return bending_from_rotation(self.rotation, "delta", 1.0)[0]

    @property
    def theta(self) -> np.ndarray:
        """(N,) the tip bending angle [rad], between the tip tangent and the base's z."""
        return np.arccos(np.clip(self.rotation[:, 2, 2], -1.0, 1.0))


# --------------------------------------------------------------------------------------------
# Inputs


def excitation(config: CosseratArm, duration_s: float, seed) -> Command:
    """The commanded inputs of one trajectory, ``command(t) -> (len(t), 4)``, drawn from
    ``seed`` (anything ``numpy.random.default_rng`` takes); every input starts at ``amplitude``
    (a straight arm at rest) and stays in [0, 2 amplitude]."""
    rng = np.random.default_rng(seed)
    A = config.amplitude
    if config.signal == "multisine":
        K = config.components
        lo, hi = math.log(config.frequency_low), math.log(config.frequency_high)
        f = np.exp(rng.uniform(lo, hi, (INPUTS, K)))
        phase = rng.uniform(0, 2 * np.pi, (INPUTS, K))
        w = rng.uniform(0.5, 1.0, (INPUTS, K))
        w /= w.sum(1, keepdims=True)
        fade = config.fade_in

        def command(t):
            t = np.asarray(t, float)[:, None, None]
            s = np.sum(w * np.sin(2 * np.pi * f * t + phase), -1)  # (N, 4)
            if fade > 0:
                s = s * np.sin(0.5 * np.pi * np.clip(t[:, :, 0] / fade, 0, 1)) ** 2
            return A * (1 + s)

        return command
    # steps: levels uniform in [0, 2 A], each held for a time uniform in [hold_low, hold_high]
    count = int((duration_s + max(config.delay)) / config.hold_low) + 2
    switches = np.cumsum(rng.uniform(config.hold_low, config.hold_high, (INPUTS, count)), 1)
    jumps = np.diff(np.concatenate([np.full((INPUTS, 1), A),
                                    rng.uniform(0, 2 * A, (INPUTS, count))], 1), axis=1)
    ramp = config.ramp

    def command(t):
        t = np.asarray(t, float)
        out = np.full((len(t), INPUTS), A)
        for j in range(INPUTS):  # half-cosine transitions of ``ramp`` seconds
            x = np.clip((t[:, None] - switches[j]) / ramp, 0, 1)
            out[:, j] += (0.5 * (1 - np.cos(np.pi * x))) @ jumps[j]
        return out

    return command


def actuator_response(config: CosseratArm, command: Command, t: np.ndarray) -> np.ndarray:
    """(len(t), 4) the applied moments on the uniform times ``t``: each command delayed by its
    dead time (held at its first value before t = 0) and passed through its first-order lag,
    started at rest; exact for inputs linear between the times."""
    t = np.asarray(t, float)
    out = np.empty((len(t), INPUTS))
    for j in range(INPUTS):  # the delayed command from its formula, then softpinn's lag
        out[:, j] = lag(t, command(np.maximum(t - config.delay[j], 0.0))[:, j], config.tau[j])
    return out


# --------------------------------------------------------------------------------------------
# The rod


def _rod_system(ea, config: CosseratArm, applied: np.ndarray, t0: float, dt: float):
    """The PyElastica simulator of the arm; ``applied`` (K, 4) the moments on the times
    t0 + k dt."""
    n, L = config.n_elements, config.length
    dl = L / n
    rod = ea.CosseratRod.straight_rod(
        n + 1, np.array([0.0, 0.0, -dl]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]),
        L + dl, config.radius, config.density, youngs_modulus=config.youngs_modulus,
        shear_modulus=config.youngs_modulus / (2 * (1 + config.poisson_ratio)),
    )
    rod.mass[-1] += config.tip_mass
    J = rod.mass_second_moment_of_inertia
    J[:, :, -1] += 0.4 * config.tip_mass * config.tip_radius**2 * np.eye(3)
    rod.inv_mass_second_moment_of_inertia[:, :, -1] = np.linalg.inv(J[:, :, -1])
    inertia = np.einsum("iik->ik", J)  # (3, n + 1), diagonal in the material frame
    g = config.gravity if config.hanging else -config.gravity  # the rod points along +z
    weight = rod.mass * g
    drag = config.damping * rod.mass[None, :]
    spin = config.rotational_damping * inertia  # the dilatation (1 +- 1e-3) left out
    # the tip moment of every input on the times, in the material frame: input j turns about
    # (-sin a_j, cos a_j, 0), bending the tip toward angle a_j
    moments = (applied @ np.stack([-np.sin(ANGLES), np.cos(ANGLES)], 1)).T.tolist()
    last = len(applied) - 1.0

    class Loads(ea.NoForces):
        """Gravity, linear damping and the tip moments (plain floats: called every step)."""

        def apply_forces(self, system, time=0.0):
            f = system.external_forces
            f -= drag * system.velocity_collection
            f[2] += weight

        def apply_torques(self, system, time=0.0):
            tq = system.external_torques
            tq -= spin * system.omega_collection
            x = min(max((float(time) - t0) / dt, 0.0), last)
            k = min(int(x), int(last) - 1)
            w = x - k
            mx, my = moments
            tq[0, -1] += mx[k] + w * (mx[k + 1] - mx[k])
            tq[1, -1] += my[k] + w * (my[k + 1] - my[k])

    sim = type("Arm", (ea.BaseSystemCollection, ea.Constraints, ea.Forcing), {})()
    sim.append(rod)
    sim.constrain(rod).using(ea.FixedConstraint, constrained_position_idx=(0, 1),
                             constrained_director_idx=(0,))
    sim.add_forcing_to(rod).using(Loads)
    sim.finalize()
    return sim, rod


def _stepper(ea, sim):
    """One integration step ``step(time, dt) -> time`` for pyelastica >= 0.3."""
    stepper = ea.PositionVerlet()
    if hasattr(stepper, "step"):  # pyelastica >= 0.4
        return lambda time, dt: stepper.step(sim, time, dt)
    do_step, stages = ea.extend_stepper_interface(stepper, sim)
    return lambda time, dt: do_step(stepper, stages, sim, time, dt)


def _rotation_noise(rng, count: int, std: float) -> np.ndarray:
    """(count, 3, 3) rotations exp([n]x), n ~ N(0, std^2 I): quaternions (cos h, sin h n / |n|),
    h = |n| / 2."""
    n = rng.normal(0.0, std, (count, 3))
    h = np.linalg.norm(n, axis=1, keepdims=True) / 2
    return quaternion_to_matrix(np.hstack([np.cos(h), np.sinc(h / np.pi) * n / 2]))


def simulate(config: CosseratArm, command: Command | None, duration_s: float, rate_hz: float,
             *, noise: float = 0.0, noise_seed=0) -> Trajectory:
    """Simulate the arm for ``duration_s`` seconds under ``command`` (``command(t) -> (N, 4)``
    commanded moments [N m]; None: all four at ``amplitude``, a straight arm) and sample its tip
    at ``rate_hz`` from t = 0, after ``config.settle`` seconds at the first command. ``noise``
    [rad]: the sensor's Gaussian rotation noise per axis, drawn from ``noise_seed``."""
    import elastica as ea  # deferred: the optional extra "cosserat" (pyelastica and numba)

    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise UserError(f"rate_hz: expected a positive number of Hz, got {rate_hz!r}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise UserError(f"duration_s: expected a positive number of seconds, got {duration_s!r}")
    if not (math.isfinite(noise) and noise >= 0):
        raise UserError(f"noise: expected a number >= 0 [rad], got {noise!r}")
    if command is None:
        command = lambda t: np.full((len(t), INPUTS), config.amplitude)  # noqa: E731
    period = 1.0 / rate_hz
    sub = max(1, math.ceil(period / config.time_step - 1e-9))
    dt = period / sub
    samples = int(round(duration_s * rate_hz)) + 1
    settle = int(round(config.settle / dt))
    grid = (np.arange(settle + (samples - 1) * sub + 2) - settle) * dt
    applied = actuator_response(config, command, grid)
    sim, rod = _rod_system(ea, config, applied, float(grid[0]), dt)
    step = _stepper(ea, sim)
    R = np.empty((samples, 3, 3))
    tip = np.empty((samples, 3))
    idx = settle + np.arange(samples) * sub  # the samples' steps on the grid
    time, done = np.float64(grid[0]), 0
    for i, stop in enumerate(idx):
        for _ in range(stop - done):
            time = step(time, dt)
        done = stop
        R[i] = rod.director_collection[:, :, -1].T
        tip[i] = rod.position_collection[:, -1]
        reach = float(np.linalg.norm(tip[i]))
        if not (np.all(np.isfinite(R[i])) and 0.5 < reach / config.length < 1.5):
            raise UserError(f"time_step: the rod simulation diverged at t = {i * period:.3f} s "
                            f"(tip {reach:.3g} m from the base); lower time_step (now "
                            f"{config.time_step:g} s)")
    t = np.arange(samples) * period
    measured = R
    if noise > 0:
        measured = R @ _rotation_noise(np.random.default_rng(noise_seed), samples, noise)
    return Trajectory(t=t, command=command(t), actuator=applied[idx], rotation=R,
                      quaternion=matrix_to_quaternion(measured), tip=tip)


# --------------------------------------------------------------------------------------------
# Recordings


@dataclass(frozen=True)
class RecordSettings:
    """What :func:`record` records. The default: 12 trajectories of 20 s at 50 Hz, as issue
    43's measure (8 to train, 4 held out); :data:`QUICK` for CI."""

    n_trajectories: int = 12
    duration_s: float = 20.0
    rate_hz: float = 50.0
    noise: float = 0.0  # [rad]
    seed: int = 0


QUICK = RecordSettings(n_trajectories=3, duration_s=3.0)


def _write(path: Path, text: str) -> None:
    """Write ``text`` whole or not at all (a temporary sibling renamed into place)."""
    remove_stale_partials(path)
    tmp = partial_path(path)
    tmp.write_text(text, encoding="utf-8")
    install_file(tmp, path)


def _csv_text(traj: Trajectory, u: np.ndarray, header: list[str]) -> str:
    names = ["t", *(f"u{j}" for j in range(INPUTS)), "qw", "qx", "qy", "qz",
             *(f"command{j}" for j in range(INPUTS)), *(f"actuator{j}" for j in range(INPUTS))]
    table = np.column_stack([traj.t, u, traj.quaternion, traj.command, traj.actuator])
    lines = [f"# {h}" for h in header] + [",".join(names)]
    lines += [",".join(f"{v:.12g}" for v in row) for row in table]
    return "\n".join(lines) + "\n"


def record(config: CosseratArm, n_trajectories: int, duration_s: float, rate_hz: float,
           noise: float, seed: int, out_dir, *, inputs: str = "command",
           overwrite: bool = False) -> list[Path]:
    """Simulate ``n_trajectories`` recordings and write each as ``out_dir/cosserat_KKK.csv`` in
    the format of ``docs/import.md`` (t, u0..u3, qw..qz; also command0..3 and actuator0..3,
    which ``softpinn import`` ignores), then ``out_dir/cosserat.json`` with the settings that
    made them. ``inputs``: ``"command"`` writes the commanded inputs as u, ``"actuator"`` the
    applied (delayed, lagged) moments, as measured pressures would be. Trajectory k's inputs
    come from ``[seed, k, 0]``, its sensor noise from ``[seed, k, 1]``: the same seed with and
    without noise gives the same motion. Every file is written whole or not at all; existing
    ones are refused unless ``overwrite`` (which also removes other ``cosserat_*.csv``).
    Returns the CSV paths."""
    if not (isinstance(n_trajectories, int) and n_trajectories >= 1):
        raise UserError(f"n_trajectories: expected an integer >= 1, got {n_trajectories!r}")
    if not (isinstance(seed, int) and seed >= 0):
        raise UserError(f"seed: expected an integer >= 0, got {seed!r}")
    if inputs not in ("command", "actuator"):
        raise UserError(f"inputs: expected command or actuator, got {inputs!r}")
    out = Path(out_dir)
    paths = [out / f"cosserat_{k:03d}.csv" for k in range(n_trajectories)]
    existing = sorted(out.glob("cosserat_*.csv")) + sorted(out.glob(SETTINGS_FILE))
    if existing and not overwrite:
        raise UserError(f"out_dir: {existing[0]} exists (pass overwrite=True to replace it)")
    try:
        out.mkdir(parents=True, exist_ok=True)
        for old in existing:
            old.unlink()
    except OSError as exc:
        raise UserError(f"out_dir: cannot write {out} ({exc.strerror})") from None
    for k, path in enumerate(paths):
        traj = simulate(config, excitation(config, duration_s, [seed, k, 0]), duration_s,
                        rate_hz, noise=noise, noise_seed=[seed, k, 1])
        header = [
            f"softpinn Cosserat-rod stand-in (symbolic/standin/_cosserat.py): trajectory {k} "
            f"of {n_trajectories}, seed {seed}; settings in {SETTINGS_FILE}",
            f"u0..u3: the {inputs} moments [N m] bending toward 0, 90, 180, 270 degrees; "
            "command*: commanded, actuator*: applied (delayed, lagged)",
            "qw..qz: tip orientation, tip frame -> base frame (z along the straight arm), "
            f"sensor noise {noise:g} rad"]
        _write(path, _csv_text(traj, traj.command if inputs == "command" else traj.actuator,
                               header))
    settings = {
        "generator": "softpinn.symbolic.standin._cosserat.record", "config": asdict(config),
        "n_trajectories": n_trajectories, "duration_s": float(duration_s),
        "rate_hz": float(rate_hz), "noise_rad": float(noise), "seed": seed, "inputs": inputs,
        "files": [p.name for p in paths],
        "import": f"softpinn import {out}/cosserat_*.csv {' '.join(IMPORT_ARGS)} --out DATA.npz",
        "pyelastica_version": metadata.version("pyelastica"), "numpy_version": np.__version__,
    }
    _write(out / SETTINGS_FILE, dumps(settings, what=SETTINGS_FILE) + "\n")
    return paths


def record_settings(config: CosseratArm, settings: RecordSettings, out_dir, **kwargs):
    """:func:`record` with a :class:`RecordSettings` (``QUICK`` for CI)."""
    return record(config, settings.n_trajectories, settings.duration_s, settings.rate_hz,
                  settings.noise, settings.seed, out_dir, **kwargs)
