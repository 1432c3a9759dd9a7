"""User-facing errors of this package.

The command line prints ``softpinn: error: <message>`` for any exception whose class sets
``softpinn_user_error = True`` and exits with status 2, without a traceback. Raise
:class:`UserError` (or a subclass) for mistakes a user can fix: bad files, bad flags, bad values.
"""

from __future__ import annotations


class UserError(ValueError):
    """A mistake in the user's input; the message names what is wrong and where."""

    softpinn_user_error = True
