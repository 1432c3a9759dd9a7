"""Settings that are clearly off for the data: one-line warnings before training starts.

:func:`setting_warnings` returns messages that start with the field they concern (the CLI
names the flag instead); :func:`learn._train.train` passes each to its ``warn`` callback, by
default :func:`warn_setting`, a warning of the ``softpinn.learn`` logger (printed on stderr
when logging is not configured; unlike :func:`warnings.warn` it never becomes an exception).
"""

from __future__ import annotations

import logging

from softpinn.learn._data import Dataset, mass_scale

#: fewer optimizer steps per epoch than this, with a batch that could be smaller, is off
MIN_STEPS_PER_EPOCH = 20
#: an initial mass diagonal this many times off the data's (either way) is off
MASS_RATIO = 100.0
#: the batch below which a smaller batch is not suggested (the default's floor)
SMALL_BATCH = 64


LOG = logging.getLogger("softpinn.learn")


def setting_warnings(config, data: Dataset, n_train: int, batch: int) -> list[str]:
    """Messages about settings of ``config`` (a TrainConfig) that are clearly off for ``data``
    with ``n_train`` training pairs in minibatches of ``batch``."""
    out = []
    steps = n_train // batch
    if steps < MIN_STEPS_PER_EPOCH and batch > SMALL_BATCH:
        better = max(SMALL_BATCH, n_train // 100)
        out.append(
            f"batch_size: {batch} on {n_train} training pairs makes {steps} optimizer step(s) "
            f"per epoch (fewer than {MIN_STEPS_PER_EPOCH}): training will stall; a batch of "
            f"{better} makes {n_train // better}"
        )
    model = config.model
    # The data fix the mass's scale only where p is trained on (a Hamiltonian network on
    # (q, p)) or where A is known. A Lagrangian network with a learned A has no scale to keep
    # (c M, c D, c G, c A move the same way), nor has a Hamiltonian network on (q, q̇) (any
    # c M⁻¹ fits, learn/_velocity.py): there M's start is a gauge, and moving M alone off the
    # other networks' scale makes the first q̈ that many times off (on task 4's data, M started
    # at the data's 0.0057 made the first pair loss 2e39 and the run never recovered).
    # A network started from an earlier run (init) does not start at mass_init.
    pinned = (model.state_kind == "momentum" if model.kind == "hamiltonian"
              else model.input_form == "known")
    if (config.init is None
            and model.kind in ("lagrangian", "lagrangian-hessian", "hamiltonian")
            and data.p is not None and pinned):
        what = "M⁻¹" if model.kind == "hamiltonian" else "M"
        scale = mass_scale(data, model.kind)
        start = 1.0 if model.mass_init is None else model.mass_init
        if max(scale / start, start / scale) >= MASS_RATIO:
            out.append(
                f"mass_init: the network's {what} starts near {start:.3g} on its diagonal, the "
                f"data's is about {scale:.3g} (from p = M q̇, median over coordinates); start "
                f"it at {scale:.3g}, or 'data' to take the data's scale"
            )
    return out


def warn_setting(message: str) -> None:
    """The default ``warn`` callback of :func:`learn._train.train`."""
    LOG.warning(message)
