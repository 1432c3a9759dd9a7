"""The preset model specs shipped with the package (``task1.toml`` ... ``task5.toml``,
``experiment.toml``): data files read by :func:`softpinn.symbolic.load_spec` through
``importlib.resources``; no code.
"""

__all__: list[str] = []
