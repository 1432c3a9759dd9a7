"""Model specs (the bottom of :mod:`softpinn.symbolic`): the TOML description of a robot read and
validated into a :class:`ModelSpec` value, with its ``[training]`` recipe, its simulated
``[sensor]`` and the orientation conventions that sensor uses. It imports no other subpackage of
symbolic; every other one may import it (order: spec -> derivation -> codegen -> model ->
simulation -> recorded). Its modules are private; the public names are re-exported by
:mod:`softpinn.symbolic`.
"""

__all__: list[str] = []
