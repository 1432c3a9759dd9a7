"""The errors a user sees: one class for mistakes a user can fix, one for training that diverged.

The command line prints ``softpinn: error: <message>`` for a :class:`UserError` (or a subclass)
and exits with status 2, without a traceback. Raise it for mistakes a user can fix: bad files,
bad flags, bad values. :class:`TrainingDiverged` (and its case :class:`NonFiniteStart`) is the
one class for a training whose loss became NaN or inf; ``softpinn.learn`` raises and re-exports
it. This module imports nothing (a leaf every layer may use).
"""

from __future__ import annotations


class UserError(ValueError):
    """A mistake in the user's input; the message names what is wrong and where."""

    softpinn_user_error = True


class TrainingDiverged(UserError):
    """The loss became NaN or inf; the last good checkpoint is kept."""


class NonFiniteStart(TrainingDiverged):
    """The untrained model's loss is already NaN or inf: nothing can be trained (a fresh run
    leaves no files behind)."""
