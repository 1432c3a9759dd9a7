"""The settings of a sweep (:class:`SweepConfig`): how many trials, how they are scheduled and
where they run; the sweep itself is :func:`softpinn.bridge.sweep.sweep`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from softpinn.errors import UserError

__all__ = ["METRICS", "SCHEDULERS", "SweepConfig"]

SCHEDULERS = ("asha", "none")
#: What ASHA compares at its rungs: the best test loss so far (it never rises), or the test loss
#: of the latest evaluation. The trials are ranked by their best test loss either way (the loss
#: of the model each run directory keeps).
METRICS = ("best_test_loss", "test_loss")


@dataclass(frozen=True)
class SweepConfig:
    """The trials of a sweep and how Ray Tune runs them.

    ``samples`` draws of the space's random settings, each with every combination of its grid,
    each with ``seeds`` seeds (one trial each); ``random_seed`` draws the random settings.
    ``address``: a Ray cluster (``"auto"``: the one this node belongs to, ``"HOST:PORT"``,
    ``"ray://HOST:10001"``); None starts a new local Ray instance (unless the process is
    connected to one already) and stops it after; ``num_cpus``: the CPUs of that local
    instance (default: all; not with ``address``, a cluster has its own).
    ``scheduler``: "asha" (asynchronous successive halving on ``metric`` at every evaluation:
    from ``grace_period`` epochs on (default a tenth of the most epochs), at rungs
    ``grace_period * reduction_factor**k``, a trial whose loss is not among the best
    ``1 / reduction_factor`` of those that reached the rung is stopped) or "none".
    ``cpus_per_trial`` / ``gpus_per_trial``: Ray resources of a trial (fractions share a GPU);
    ``max_concurrent``: at most that many trials at once (default: as the resources allow).
    """

    samples: int = 1
    seeds: int = 1
    random_seed: int = 0
    address: str | None = None
    num_cpus: int | None = None
    scheduler: str = "asha"
    metric: str = "best_test_loss"
    grace_period: int | None = None
    reduction_factor: float = 2
    cpus_per_trial: float = 1
    gpus_per_trial: float = 0
    max_concurrent: int | None = None

    def __post_init__(self):
        if self.scheduler not in SCHEDULERS:
            raise UserError(f"scheduler: expected one of {', '.join(SCHEDULERS)}, got "
                            f"{self.scheduler!r}")
        if self.metric not in METRICS:
            raise UserError(f"metric: expected one of {', '.join(METRICS)}, got "
                            f"{self.metric!r}")
        for name, low in (("cpus_per_trial", 0), ("gpus_per_trial", None)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or (v <= 0 if low == 0 else v < 0):
                raise UserError(f"{name}: expected a number {'> 0' if low == 0 else '>= 0'}, "
                                f"got {v!r}")
        for name in ("max_concurrent", "grace_period", "num_cpus"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
                raise UserError(f"{name}: expected an integer >= 1, got {v!r}")
        v = self.reduction_factor
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 1:
            raise UserError(f"reduction_factor: expected a number > 1, got {v!r}")
        if self.address is not None and self.num_cpus is not None:
            raise UserError("num_cpus: sizes a local Ray instance; a cluster (address) has its "
                            "own")
