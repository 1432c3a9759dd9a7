"""How a simulation integrates (:class:`SimulationConfig`), what it returns (:class:`SimResult`)
and the errors it raises (:class:`SimulationError`, :class:`SingularityError`); the integration
itself is :mod:`symbolic.simulation._simulate`'s.

The output grid is t_k = k / rate, k = 0 .. round(duration * rate) - 1 (so 10 s at 50 Hz are
500 samples, as counted in Table III).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from softpinn.errors import UserError

INTEGRATORS = ("cvodes", "rk4")
#: the most output samples per trajectory and RK4 steps per output interval
MAX_SAMPLES = 1e9
MAX_SUBSTEPS = 1_000_000


class SimulationError(UserError):
    """A simulation that cannot be carried out as asked."""


class SingularityError(SimulationError):
    """The state reached a singularity (non-finite, ill-conditioned, or cvodes failed)."""


@dataclass(frozen=True)
class SimulationConfig:
    """How to integrate.

    ``rate`` is the output rate [Hz]; ``dt`` the fixed RK4 step (default ``1 / rate``), which
    must divide the output interval. ``rtol``/``atol`` are cvodes' tolerances. ``max_condition``
    bounds cond(M(q)) at every ``condition_stride``-th output sample (None: no check; non-finite
    states and cvodes failures are caught at every step regardless); ``max_num_steps`` bounds
    cvodes' steps per output interval. ``threads`` is the number of
    trajectories integrated at once.
    """

    integrator: str = "cvodes"
    duration: float = 10.0
    rate: float = 100.0
    dt: float | None = None
    rtol: float = 1e-10
    atol: float = 1e-10
    max_num_steps: int = 20_000
    max_condition: float | None = 1e12
    condition_stride: int = 10
    threads: int = 2

    def __post_init__(self):
        if self.integrator not in INTEGRATORS:
            raise SimulationError(
                f"integrator: expected one of {', '.join(INTEGRATORS)}, got {self.integrator!r}"
            )
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise SimulationError(f"duration: must be positive, got {self.duration}")
        if not (np.isfinite(self.rate) and self.rate > 0):
            raise SimulationError(f"rate: must be a positive number of Hz, got {self.rate}")
        if not self.duration * self.rate <= MAX_SAMPLES:
            raise SimulationError(
                f"duration * rate: {self.duration:g} s at {self.rate:g} Hz gives more than "
                f"{MAX_SAMPLES:.0e} samples per trajectory"
            )
        if self.samples < 2:
            raise SimulationError(
                f"duration * rate: must give at least 2 samples, got "
                f"{self.duration} s at {self.rate} Hz"
            )
        if self.dt is not None:
            if not (np.isfinite(self.dt) and self.dt > 0):
                raise SimulationError(f"dt: must be positive, got {self.dt}")
            ratio = 1.0 / (self.rate * self.dt)
            if not ratio <= MAX_SUBSTEPS:
                raise SimulationError(
                    f"dt: {self.dt:g} s makes {ratio:.3g} RK4 steps per output interval "
                    f"(1/rate = {1 / self.rate:g} s), more than {MAX_SUBSTEPS:,}; use a larger dt"
                )
            if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
                raise SimulationError(
                    f"dt: the output interval 1/rate = {1 / self.rate:g} s must be a whole "
                    f"multiple of dt = {self.dt:g} s"
                )
        for name in ("rtol", "atol"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise SimulationError(f"{name}: must be positive, got {v}")
        if self.condition_stride < 1:
            raise SimulationError(
                f"condition_stride: must be at least 1, got {self.condition_stride}"
            )
        if self.threads < 1:
            raise SimulationError(f"threads: must be at least 1, got {self.threads}")

    @property
    def samples(self) -> int:
        return int(round(self.duration * self.rate))

    @property
    def step(self) -> float:
        return self.dt if self.dt is not None else 1.0 / self.rate

    @property
    def substeps(self) -> int:
        return int(round(1.0 / (self.rate * self.step)))

    def times(self) -> np.ndarray:
        return np.arange(self.samples) / self.rate

    def describe(self) -> dict:
        """What goes into a dataset's ``meta`` (integrator, tolerances or step, rate)."""
        d = asdict(self)
        if self.integrator == "cvodes":
            d.pop("dt")
            d["method"] = "cvodes (SUNDIALS CVODES, variable-step BDF, Newton, dense, FD Jacobian)"
        else:
            for k in ("rtol", "atol", "max_num_steps"):
                d.pop(k)
            d["dt"] = self.step
            d["substeps_per_sample"] = self.substeps
            d["method"] = "classical Runge-Kutta 4, fixed step"
        d["samples_per_trajectory"] = self.samples
        d["input"] = "exact: u(t) evaluated symbolically in t inside the integrator"
        return d


@dataclass
class SimResult:
    """Trajectories on the output grid: ``x`` (K, T, 2n), ``u`` (K, T, m), ``qdd`` and ``p``
    (K, T, n), ``t`` (T,)."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    qdd: np.ndarray
    p: np.ndarray
    config: SimulationConfig
    info: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.qdd.shape[-1]

    @property
    def q(self) -> np.ndarray:
        return self.x[..., : self.n]

    @property
    def qd(self) -> np.ndarray:
        return self.x[..., self.n :]
