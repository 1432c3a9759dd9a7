"""One progress protocol: long work says how far it got by calling ``progress(event)`` with one
:class:`Progress` event (``progress`` None: nothing is reported). The command line draws its
bars from the events (:mod:`softpinn.bridge.cli.bars`); a library caller may pass any callable,
e.g. ``events.append``. Standard library only: symbolic, learn and bridge all import it.

Who reports what (the event's ``unit``):

* training (:func:`softpinn.learn.train`): ``"epoch"`` of AdamW, then ``"iteration"`` of the
  L-BFGS finish, as a :class:`TrainProgress` that carries the losses;
* simulation (:func:`softpinn.symbolic.make_dataset`, :mod:`softpinn.bridge.exact`):
  ``"trajectory"``, as chunks of trajectories finish;
* the comparison of learned and true matrices (:mod:`softpinn.bridge.analysis`): ``"stage"``;
* ``reproduce --jobs`` (:mod:`softpinn.bridge.tasks`): ``"model"``, and each model's training
  events with :attr:`TrainProgress.model` set to its key.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True, kw_only=True)
class Progress:
    """``done`` of ``total`` units of the work finished (``total`` None: not known)."""

    done: int
    total: int | None = None
    #: what is counted: "epoch", "iteration", "trajectory", "stage", "model", ...
    unit: str = ""
    #: whose work: a group of seeds, a stage's name, a model's key ("" where there is one)
    label: str = ""
    #: which part of the work: "adamw", "lbfgs"; "start" and "done" of a model; ...
    phase: str = ""


@dataclass(frozen=True, kw_only=True)
class TrainProgress(Progress):
    """One epoch of a training (the group of seeds ``label``): ``done`` of ``total`` AdamW
    epochs (phase "adamw", unit "epoch"; ``done`` 0: the untrained model) or L-BFGS iterations
    (phase "lbfgs", unit "iteration"), with each member's losses after it."""

    #: the epoch of the run's history (L-BFGS chunks count on after the AdamW epochs)
    epoch: int
    #: the AdamW epochs of the run
    epochs: int
    seeds: tuple[int, ...] = ()
    train_loss: tuple[float, ...] = ()
    #: None where this epoch was not evaluated on the test set
    test_loss: tuple[float, ...] | None = None
    best_test_loss: tuple[float, ...] = ()
    #: the members still training
    active: tuple[bool, ...] = ()
    #: training seconds so far
    seconds: float = 0.0
    #: the model's key where several train side by side (``reproduce --jobs``)
    model: str = ""


class ProgressFn(Protocol):
    """What takes the events: ``progress(event)``."""

    def __call__(self, event: Progress, /) -> None: ...
