"""Errors of the exact-model translation."""

from __future__ import annotations

from softpinn.errors import UserError


class TranslationError(UserError):
    """A CasADi Function that cannot be replayed in JAX, or a call with wrong inputs."""


__all__ = ["TranslationError"]
