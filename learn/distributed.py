"""Training on several processes (hosts): :func:`initialize` joins this process to the others
through ``jax.distributed`` (a coordinator address, or the environment of a cluster that JAX
detects by itself: SLURM, Open MPI), after which ``--devices all`` spans every process's devices
(:mod:`learn._programs`: one data-parallel mesh, gradients reduced by XLA across hosts).

Every process loads the same data file and runs the same training; process 0 writes the run
directory, the others write into a private shadow copy that is removed at the end (on a
resume they start from a copy of the shared run directory, so every process can resume)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import jax

from softpinn.errors import UserError


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, *, cluster: bool = False) -> None:
    """Join the other processes: with ``coordinator`` ("host:port" of process 0),
    ``num_processes`` and ``process_id``, or ``cluster=True`` to take them from the cluster's
    environment. On CPUs the collectives run over Gloo."""
    given = [coordinator is not None, num_processes is not None, process_id is not None]
    if cluster and any(given):
        raise UserError("coordinator: give --cluster or --coordinator/--num-processes/"
                        "--process-id, not both")
    if not cluster and not all(given):
        if any(given):
            raise UserError("coordinator: --coordinator, --num-processes and --process-id go "
                            "together")
        return
    if not cluster:
        host, sep, port = str(coordinator).rpartition(":")
        if not sep or not host or not port.isdigit():
            raise UserError(f"coordinator: expected HOST:PORT, got {coordinator!r}")
        if not 1 <= int(port) <= 65535:  # issue 44: a port no process can listen on
            raise UserError(f"coordinator: port {int(port)} of {coordinator!r} is not a TCP "
                            "port (1 to 65535)")
        if not (isinstance(num_processes, int) and num_processes >= 1):
            raise UserError(f"num_processes: expected an integer >= 1, got {num_processes!r}")
        if not (isinstance(process_id, int) and 0 <= process_id < num_processes):
            raise UserError(f"process_id: expected an integer in [0, {num_processes}), got "
                            f"{process_id!r}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        if cluster:
            jax.distributed.initialize()
        else:
            jax.distributed.initialize(coordinator_address=coordinator,
                                       num_processes=num_processes, process_id=process_id)
    except (RuntimeError, ValueError) as exc:
        raise UserError(f"coordinator: could not join the other processes ({exc})") from None


def is_writer() -> bool:
    """Whether this process writes the run directory (process 0, or the only one)."""
    return jax.process_index() == 0


def shadow_dir(run_dir: str | Path, *, resume: bool) -> Path:
    """Where a process other than 0 writes: a private folder (a copy of ``run_dir`` when
    resuming)."""
    shadow = Path(tempfile.mkdtemp(prefix=f"softpinn-process{jax.process_index()}-")) / "run"
    if resume:
        shutil.copytree(run_dir, shadow)
    return shadow


def drop_shadow(path: Path) -> None:
    shutil.rmtree(path.parent, ignore_errors=True)
