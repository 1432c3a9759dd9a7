"""Hyperparameter sweeps and seed ensembles through Ray Tune (``pip install 'softpinn[ray]'``).

:func:`sweep` trains one :func:`softpinn.learn.train` run per trial, a grid and/or random
draws over :class:`softpinn.learn.TrainConfig` settings times seeds (:mod:`.space`), on a local
Ray instance or a Ray cluster (:class:`SweepConfig`), with ASHA stopping the worse trials early
(:mod:`.tuner`, :mod:`.trial`), and writes (:mod:`.results`)::

    OUT/trials/<name>/   every trial a normal run directory (predict, analyze, --resume)
    OUT/results.csv      one row per trial: settings, best test loss, epochs run, stopped
    OUT/results.json     early, status, seconds; the best trial's folder
    OUT/results.md       the same, ranked, with the plot and the best trial linked
    OUT/sweep.png        best test loss against each swept setting (log scale)
    OUT/best             a link to the best trial's folder
    OUT/tune/            Ray Tune's own experiment folder (its logs and per-trial results)

Modules: :mod:`.config` (SweepConfig), :mod:`.space` (settings, ranges, trials),
:mod:`.launch` (:func:`sweep`), :mod:`.tuner` and :mod:`.trial` (Ray Tune), :mod:`.rows` (a
trial's row and status), :mod:`.results` (the files). Ray is imported only inside
:func:`sweep` (:mod:`.tuner` and :mod:`.trial` import it, and only it imports them), so
``import softpinn.bridge`` works without it.
"""

from softpinn.bridge.sweep.config import METRICS, SCHEDULERS, SweepConfig
from softpinn.bridge.sweep.launch import RAY_MISSING, sweep
from softpinn.bridge.sweep.results import SweepResult
from softpinn.bridge.sweep.space import Random, Trial, make_trials, parse_space

__all__ = ["METRICS", "RAY_MISSING", "SCHEDULERS", "Random", "SweepConfig", "SweepResult",
           "Trial", "make_trials", "parse_space", "sweep"]
