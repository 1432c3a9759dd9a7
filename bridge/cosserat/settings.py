"""The settings of ``softpinn reproduce cosserat`` (:mod:`.pipeline`): the recordings, the two
variants (clean, and with sensor noise), the networks' small recipe, the horizons.

Budgets. ``full``: 12 recordings of 20 s at 50 Hz (8 to train, 4 held out for test, as issue
43's measure), each network trained to fit "8 trajectories of 20 s at 50 Hz in under 10 minutes
on 2 cores" (:data:`FULL_NETWORKS`); ``quick`` (CI): the stand-in's ``QUICK`` recordings (3 of
3 s) and a few epochs of small networks, horizons clipped to the recordings.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

#: the networks, in the report's order: kind, the label the report gives it
NETWORKS = (
    ("blackbox", "black box"),
    ("lagrangian", "Lagrangian"),
    ("hamiltonian", "Hamiltonian-from-velocity"),
)
#: ``softpinn import``'s arguments for the stand-in's files (``docs/import.md``): a one-segment
#: spatial arm with four inputs, d = 1, the tip orientation as a quaternion
IMPORT_MODEL = "experiment"
IMPORT_ORIENTATION = "quaternion"
#: the sensor noise of the noisy variant [rad per axis]: the ``experiment`` preset's IMU
NOISE = 0.01
#: the noisy variant's smoother: Savitzky-Golay cubics over 0.8 s at 50 Hz, as
#: ``docs/experiment.md`` takes them (``savgol:41:3``)
SAVGOL_WINDOW_S, SAVGOL_DEGREE = 0.8, 3


@dataclass(frozen=True)
class Network:
    """One network's recipe: sizes ((width, depth) of each sub-network, as ``softpinn train``'s
    ``--mass`` etc.), budget and optimiser."""

    kind: str  # "blackbox", "lagrangian", "hamiltonian" (trained from velocities)
    epochs: int
    lr: float
    mass: tuple[int, int] = (32, 2)
    potential: tuple[int, int] = (32, 2)
    damping: tuple[int, int] = (16, 2)
    input: tuple[int, int] = (16, 2)
    hidden: tuple[int, int] = (64, 3)

    @property
    def momenta(self) -> str:
        """A Hamiltonian network trains on (q, q̇): no robot measures momenta
        (``softpinn train --momenta velocity``, :mod:`bridge.challenges.velocity`)."""
        return "velocity" if self.kind == "hamiltonian" else "auto"


#: full: about 100 optimizer steps per epoch on 6,000 pairs (batch 64); the experiment
#: recipe's learning rates
FULL_NETWORKS = (
    Network("blackbox", epochs=150, lr=2e-3, hidden=(60, 3)),
    Network("lagrangian", epochs=100, lr=5e-3),
    Network("hamiltonian", epochs=100, lr=5e-3),
)
QUICK_NETWORKS = (
    Network("blackbox", epochs=4, lr=2e-3, hidden=(16, 2)),
    Network("lagrangian", epochs=4, lr=5e-3, mass=(8, 2), potential=(8, 2), damping=(8, 1),
            input=(8, 1)),
    Network("hamiltonian", epochs=4, lr=5e-3, mass=(8, 2), potential=(8, 2), damping=(8, 1),
            input=(8, 1)),
)


@dataclass(frozen=True)
class CosseratPlan:
    """What a run does (written to ``OUT/plan.json``; every stage's settings come from it)."""

    quick: bool
    trajectories: int  # recorded per variant
    duration_s: float
    rate_hz: float
    test_trajectories: int  # the last ones, held out and scored
    validation_trajectories: int  # the last training ones: best epoch chosen on them
    seed: int  # of the recordings (inputs and noise); the networks' is ``train_seed``
    train_seed: int
    variants: Mapping[str, Mapping[str, Any]]  # name -> {"noise", "smooth", "differences"}
    networks: tuple[Network, ...]
    horizons: tuple[float, ...]  # [s]
    samples: int | None  # training pairs drawn (None: all)
    batch_size: int
    input_hold: str
    loss: str
    arm: Mapping[str, Any] = field(default_factory=dict)  # CosseratArm changes (none: defaults)
    #: the actuator between the recorded commands and the rod (``softpinn train --actuator``):
    #: ``identify`` (from the training trajectories, as a user without the stand-in's numbers
    #: would), ``none``, or ``TAU:DELAY``; every network and baseline gets the same
    actuator: str = "identify"
    #: the networks' linear prior (``TrainConfig.prior``): auto gives linear on the imported
    #: recordings, so the networks start as the linear model (least squares or rollout fit)
    prior: str = "auto"
    #: what picks the best epoch on the validation trajectories (``TrainConfig.test_with``):
    #: rollouts of up to 5 s, as ``softpinn train`` does on imported recordings
    test_with: str = "rollout"

    def network(self, kind: str) -> Network:
        return next(n for n in self.networks if n.kind == kind)

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self)))


def savgol(rate_hz: float) -> str:
    """``--smooth`` of the noisy variant at ``rate_hz``: cubics over :data:`SAVGOL_WINDOW_S`
    (an odd window of at least 5 samples)."""
    w = max(5, int(round(SAVGOL_WINDOW_S * rate_hz)))
    w += 1 - w % 2
    return f"savgol:{w}:{SAVGOL_DEGREE}"


def make_plan(quick: bool, record_quick) -> CosseratPlan:
    """The plan of a full or quick run; ``record_quick``: the stand-in's quick recording
    settings (``softpinn.symbolic.COSSERAT_QUICK``)."""
    if quick:
        count, duration, rate = (record_quick.n_trajectories, record_quick.duration_s,
                                 record_quick.rate_hz)
        test, validation, networks, samples = 1, 1, QUICK_NETWORKS, None
        horizons = (1.0, min(5.0, duration))
    else:
        count, duration, rate = 12, 20.0, 50.0
        test, validation, networks, samples = 4, 1, FULL_NETWORKS, 6000
        horizons = (1.0, 5.0)
    variants = {
        "clean": {"noise": 0.0, "smooth": "none", "differences": 2},
        "noisy": {"noise": NOISE, "smooth": savgol(rate), "differences": 2},
    }
    return CosseratPlan(quick=quick, trajectories=count, duration_s=duration, rate_hz=rate,
                        test_trajectories=test, validation_trajectories=validation, seed=0,
                        train_seed=0, variants=variants, networks=networks, horizons=horizons,
                        samples=samples, batch_size=64, input_hold="linear", loss="pair")
