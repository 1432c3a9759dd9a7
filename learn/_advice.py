"""Settings that are clearly off for the data: one-line warnings before training starts.

:func:`setting_warnings` returns messages that start with the field they concern (the CLI
names the flag instead); :func:`learn._train.train` passes each to its ``warn`` callback, by
default :func:`warn_setting`, a warning of the ``softpinn.learn`` logger (printed on stderr
when logging is not configured; unlike :func:`warnings.warn` it never becomes an exception).
"""

from __future__ import annotations

import logging

import numpy as np

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
    out += scale_warnings(data)
    return out


#: a column whose rms is further than this from 1 (either way) is off for a network's input
SCALE_RATIO = 100.0


def scale_warnings(data: Dataset) -> list[str]:
    """Inputs or coordinates whose scale is far from 1 (issue 43: bending of 0.05 rad and
    pressures in Pa went into the networks unscaled, and nothing warned). Networks are not
    normalised inside: on the Cosserat stand-in, inputs normalised to zero mean and unit
    variance changed the Lagrangian's rollout errors by under 2 % (RESULTS.md), so a scale near
    1 is left to the user's units; far off it, they say so here."""
    out = []
    for key, what, fix in (("u", "inputs u", "e.g. bar or kPa instead of Pa, N instead of mN"),
                           ("q", "coordinates q", "a coordinate that barely moves, such as a "
                            "stiff stretch, is better left out, e.g. import --observed-only")):
        with np.errstate(over="ignore"):  # values near 1e155 and more: the loss's message
            rms = np.sqrt(np.mean(getattr(data, key) ** 2, axis=0))
        bad = [(j, float(r)) for j, r in enumerate(rms)
               if np.isfinite(r) and r > 0 and max(r, 1 / r) >= SCALE_RATIO]
        if bad:
            j, r = bad[0]
            out.append(f"the data's {what} have rms {r:.3g} (column {j}"
                       f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}), {SCALE_RATIO:g}x "
                       f"or more from 1; the networks see them unscaled: rescale them ({fix})")
    return out


def warn_setting(message: str) -> None:
    """The default ``warn`` callback of :func:`learn._train.train`."""
    LOG.warning(message)


#: the optimizer steps the budget chosen for recordings aims at: the Cosserat study's recipe
#: (100 epochs of about 94 steps) reached its best validation loss within it
RECORDING_STEPS = 10_000
#: the peak learning rates of the experiment recipe: physics networks, black box
RECORDING_LR = {"blackbox": 2e-3}
RECORDING_LR_PHYSICS = 5e-3


def recording_defaults(data: Dataset, pairs: int, kind: str, given) -> tuple[dict, str | None]:
    """Settings chosen from recorded data (a file of ``softpinn import``; issue 43, item 5) for
    every one the user did not give (``given``: the setting names typed): a budget of about
    :data:`RECORDING_STEPS` optimizer steps on ``pairs`` training pairs (the CLI default of 1,000
    epochs took 70 minutes on a recorded arm), the recipe's learning rate, inputs linear
    between samples (recorded commands are samples of a continuous signal), and held-out
    rollouts (``test_with`` "rollout") to pick the best epoch. Returns the
    settings and one line that says what was chosen and why (None: nothing chosen)."""
    if data.meta.get("source") != "import":
        return {}, None
    chosen: dict = {}
    why = []
    batch = max(SMALL_BATCH, pairs // 100)
    if "epochs" not in given and "batch_size" not in given:
        steps = max(1, pairs // batch)
        chosen["epochs"] = int(min(1000, max(20, -(-RECORDING_STEPS // steps))))
        why.append(f"epochs {chosen['epochs']} (about {RECORDING_STEPS:,} optimizer steps of "
                   f"batch {batch} on {pairs:,} pairs)")
    if "lr" not in given:
        chosen["lr"] = RECORDING_LR.get(kind, RECORDING_LR_PHYSICS)
        why.append(f"lr {chosen['lr']:g}")
    if "input_hold" not in given:
        chosen["input_hold"] = "linear"
        why.append("input hold linear (recorded inputs are samples of a continuous signal)")
    if "test_with" not in given:
        chosen["test_with"] = "rollout"
        span = "--test-steps steps" if "test_steps" in given else "up to 5 s"
        why.append(f"the best epoch picked by held-out rollouts of {span} (predict's error; "
                   "a one-step loss on noisy derivatives can improve while rollouts get worse)")
    if not chosen:
        return {}, None
    return chosen, ("settings for recorded data (this file is an import): " + ", ".join(why)
                    + "; a flag overrides any")
