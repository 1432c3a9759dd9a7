"""Data generation across a Ray cluster (issue 21, part 4): trajectories farmed out in chunks
give the same data set, to the bit, as the in-process integration."""

from __future__ import annotations

import numpy as np
import pytest
import ray

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.symbolic.simulation._datasets import make_dataset
from softpinn.symbolic.simulation._farm import ray_init, ray_simulator
from softpinn.symbolic.spec._spec import load_spec


@pytest.fixture(scope="module")
def local_ray():
    ray_init(ray, num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    yield
    ray.shutdown()


@pytest.mark.parametrize("task", ["task1", "task4"])
def test_farmed_out_data_set_is_identical(local_ray, task):
    opts = dict(trajectories=3, duration=0.5)
    here = make_dataset(task, compile=False, **opts)
    done = []
    farmed = make_dataset(task, simulator=ray_simulator(load_spec(task), chunks=2,
                                                        compile=False),
                          progress=done.append, **opts)
    for key in ("t", "q", "qd", "qdd", "p", "u", "traj"):
        assert np.array_equal(getattr(here, key), getattr(farmed, key)), key
    # two chunks, each counted when it came back
    assert [e.done for e in done] == [2, 3] and {e.total for e in done} == {3}


def test_bad_settings_are_one_line(tmp_path, capsys):
    with pytest.raises(UserError, match="chunks: expected an integer >= 1"):
        ray_simulator(load_spec("task1"), chunks=0)
    assert main(["simulate", "task1", "--ray", "--integrator", "jax-rk4", "--trajectories",
                 "1", "--duration", "0.2", "--quiet", "--out", str(tmp_path / "d.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--ray: farms out the CasADi integrators" in err[0]
