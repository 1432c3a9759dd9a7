"""The devices a run trains on: how many (:func:`resolve_devices`), how a minibatch is split over
them (data parallel, :func:`batch_sharding`) and the arrays replicated over every process's
devices when training spans several processes (:func:`replicated`, :func:`local_copy`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from softpinn.errors import UserError


def resolve_devices(devices: int) -> int:
    """The number of devices a run uses: ``devices``, or all there are for 0; refused with one
    line when more are asked for than there are."""
    have = jax.device_count()
    use = have if devices == 0 else devices
    if jax.process_count() > 1 and use != have:
        raise UserError(f"devices: training on {jax.process_count()} processes spans every "
                        f"process's devices ({have}); give --devices all")
    if use > have:
        hint = (" (on a CPU, XLA_FLAGS=--xla_force_host_platform_device_count=N before Python "
                "starts makes N devices)" if jax.default_backend() == "cpu" else "")
        raise UserError(f"devices: {use} asked for, {have} {jax.default_backend()} device(s) "
                        f"here{hint}")
    return use


def batch_sharding(devices: int):
    """How a minibatch is laid out over ``devices``: split along its first axis (data
    parallel); None for one device. The parameters stay replicated, and XLA reduces the
    gradients over the devices (no hand-written all-reduce)."""
    if devices <= 1:
        return None
    mesh = Mesh(np.asarray(jax.devices()[:devices]), ("data",))
    return NamedSharding(mesh, PartitionSpec("data"))


def replicated(tree, devices: int):
    """``tree`` as global arrays replicated over the first ``devices`` devices of every process
    (each process holds the same values: the same data file and seed)."""
    mesh = Mesh(np.asarray(jax.devices()[:devices]), ("data",))
    rep = NamedSharding(mesh, PartitionSpec())

    def one(a):
        host = np.asarray(a)
        return jax.make_array_from_callback(host.shape, rep, lambda idx: host[idx])

    return jax.tree.map(one, tree)


def local_copy(tree):
    """This process's copy of replicated global arrays, as ordinary local arrays."""
    return jax.tree.map(lambda a: jnp.asarray(a.addressable_data(0)), tree)
