"""The installed version of softpinn (``softpinn.__version__``), for the files that record it.
A leaf: it imports the standard library only, so any layer may use it without importing the
package root."""

from __future__ import annotations

from importlib import metadata as _metadata

__all__ = ["__version__"]

try:
    __version__ = _metadata.version("softpinn")
except _metadata.PackageNotFoundError:  # pragma: no cover - running from an uninstalled tree
    __version__ = "0+unknown"
