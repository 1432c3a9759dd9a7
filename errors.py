"""The errors a user sees: one class for mistakes a user can fix, one for training that diverged.

The command line prints ``softpinn: error: <message>`` for a :class:`UserError` (or a subclass)
and exits with status 2, without a traceback. Raise it for mistakes a user can fix: bad files,
bad flags, bad values. This module imports nothing (a leaf every layer may use).
"""

from __future__ import annotations


class UserError(ValueError):
    """A mistake in the user's input; the message names what is wrong and where."""

    softpinn_user_error = True
