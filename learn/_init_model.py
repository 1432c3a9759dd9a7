"""A warm start (``TrainConfig.init``, ``train --init RUN``): the best model of an earlier run
as every member's starting point, refused with one line where its network differs."""

from __future__ import annotations

from pathlib import Path

import jax

from softpinn.errors import UserError
from softpinn.learn._models import make_model
from softpinn.learn._rundir import load_run

__all__ = ["initial_model"]


def initial_model(run_dir: str, model_config):
    """The best model of the run in ``run_dir`` (``TrainConfig.init``), which must have the
    network ``model_config``."""
    if not Path(run_dir).is_dir():
        raise UserError(f"init: {run_dir} is not a run folder")
    run = load_run(run_dir)
    theirs, ours = _network_of(run.model_config), _network_of(model_config)
    if theirs != ours:
        diff = sorted(k for k in ours if theirs.get(k) != ours[k])
        hint = ("; the linear prior (--prior) is fitted on the training trajectories: give "
                "this run the --prior and split of that one" if "prior" in diff else "")
        raise UserError(f"init: the run in {run_dir} has another network (differs in "
                        f"{', '.join(diff)}){hint}")
    if run.model_config == model_config:
        return run.model
    # the same network under this run's configuration (a size it does not use differs): its
    # parameters in the structure of a model built from model_config
    shape = jax.tree_util.tree_structure(make_model(model_config, key=jax.random.PRNGKey(0)))
    leaves = jax.tree_util.tree_leaves(run.model)
    if shape.num_leaves != len(leaves):  # not expected: the networks compared equal
        raise UserError(f"init: the run in {run_dir} has another network")
    return jax.tree_util.tree_unflatten(shape, leaves)


def _network_of(model_config) -> dict:
    """The settings that make the network: a physics model's ignore the black box's size
    (``hidden``) and a black box's the physics networks' sizes."""
    d = model_config.to_dict()
    unused = (("mass", "potential", "damping", "input") if d.get("kind") == "blackbox"
              else ("hidden",))
    return {k: v for k, v in d.items() if k not in unused}
