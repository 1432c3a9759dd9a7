"""Dataset files: [data] validation, seeded generation, exact keys/shapes/meta, round trip,
resampling and the paper's splits."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from softpinn.symbolic.simulation import _datasets as datasets
from softpinn.symbolic.simulation._datasets import (
    DataError,
    data_config,
    make_dataset,
    paper_splits,
    read_dataset,
    resample,
    select_trajectories,
    signals_of,
    split,
    take_samples,
    write_dataset,
)
from softpinn.symbolic.spec._spec import load_spec, spec_from_toml


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def task4_data(cache):
    return make_dataset("task4", trajectories=3, duration=0.5, cache=cache)


def test_task4_dataset_keys_shapes_and_meta(task4_data, tmp_path):
    d = task4_data
    T = 3 * 100  # 0.5 s at the preset's 200 Hz
    assert d.t.shape == (T,) and d.traj.shape == (T,) and d.traj.dtype == np.int64
    for key in ("q", "qd", "qdd", "p"):
        assert getattr(d, key).shape == (T, 3) and getattr(d, key).dtype == np.float64
    assert d.u.shape == (T, 3)
    np.testing.assert_array_equal(d.traj, np.repeat([0, 1, 2], 100))
    np.testing.assert_allclose(d.t[:100], np.arange(100) / 200.0)
    meta = d.meta
    assert meta["format"] == "softpinn-dataset" and meta["format_version"] == 1
    assert meta["spec"] == load_spec("task4").to_dict()
    assert meta["n"] == 3 and meta["m"] == 3 and meta["trajectories"] == 3
    sim = meta["simulation"]
    assert sim["integrator"] == "cvodes" and sim["rtol"] == 1e-10 and sim["atol"] == 1e-10
    assert sim["rate"] == 200.0 and "exact" in sim["input"]
    assert meta["seed"] == 4 and meta["noise"]["sigma"] == 0.0
    assert meta["package_version"] and meta["casadi_version"]
    assert len(meta["signals"]) == 3 and meta["signals"][0]["kind"] == "sinusoid"
    # initial states in the preset's ranges, and the recorded ones are the first samples
    x0 = np.array(meta["initial_states"])
    cfg = data_config(load_spec("task4"))
    assert np.all(x0[:, :3] >= cfg.q0_low) and np.all(x0[:, :3] <= cfg.q0_high)
    np.testing.assert_array_equal(np.hstack([d.q, d.qd])[d.t == 0], x0)
    # the recorded signals reproduce u exactly, and their parameters are in the preset's ranges
    for k, sig in enumerate(signals_of(d)):
        rows = d.traj == k
        np.testing.assert_array_equal(sig(d.t[rows]), d.u[rows])
        assert np.all(np.asarray(sig.amplitude) >= cfg.ranges["amplitude_low"])
        assert np.all(np.asarray(sig.frequency) <= cfg.ranges["frequency_high"])
    # round trip through the file, exactly
    path = write_dataset(tmp_path / "d.npz", d)
    back = read_dataset(path)
    for key in datasets.ARRAY_KEYS:
        np.testing.assert_array_equal(getattr(back, key), getattr(d, key))
    assert back.meta == json.loads(json.dumps(meta))
    with np.load(path) as z:
        assert sorted(z.files) == sorted([*datasets.ARRAY_KEYS, "meta"])
        assert z["meta"].shape == () and z["meta"].dtype.kind == "U"
    assert not list(tmp_path.glob(".*"))  # no temporary file left


def test_learn_side_loader_accepts_the_file(task4_data, tmp_path):
    from softpinn.learn._data import load_dataset

    path = write_dataset(tmp_path / "d.npz", task4_data)
    loaded = load_dataset(path, n=3, m=3)
    np.testing.assert_array_equal(loaded.qdd, task4_data.qdd)


def test_seeding_per_trajectory(cache):
    a = make_dataset("task1", trajectories=3, duration=1.0, cache=cache)
    b = make_dataset("task1", trajectories=2, duration=1.0, cache=cache)
    c = make_dataset("task1", trajectories=2, duration=1.0, seed=99, cache=cache)
    # trajectory k is the same whatever the count; another seed gives other trajectories
    np.testing.assert_array_equal(a.q[a.traj < 2], b.q)
    assert not np.allclose(c.q[:1], b.q[:1])
    assert a.meta["seed"] == 1 and c.meta["seed"] == 99


def test_noise_is_recorded_and_seeded(cache):
    clean = make_dataset("task1", trajectories=2, duration=2.0, cache=cache)
    noisy = make_dataset("task1", trajectories=2, duration=2.0, noise=0.01, cache=cache)
    again = make_dataset("task1", trajectories=2, duration=2.0, noise=0.01, cache=cache)
    np.testing.assert_array_equal(noisy.q, again.q)
    diff = noisy.q - clean.q
    assert 0.007 < diff.std() < 0.013
    np.testing.assert_array_equal(noisy.t, clean.t)
    np.testing.assert_array_equal(noisy.u, clean.u)
    assert noisy.meta["noise"]["sigma"] == 0.01
    assert noisy.meta["noise"]["arrays"] == ["q", "qd", "qdd", "p"]


@pytest.mark.parametrize("integrator", ["cvodes", "rk4"])
def test_settle_drops_the_release_transient(cache, integrator):
    kw = dict(trajectories=2, rate=50.0, integrator=integrator, cache=cache)
    kw |= {"dt": 0.005} if integrator == "rk4" else {}
    whole = make_dataset("task1", duration=1.5, **kw)
    settled = make_dataset("task1", duration=1.0, settle=0.5, **kw)
    # the recording is the last second of a 1.5 s run from the same drawn state and signal
    tail = whole.t >= 0.5 - 1e-12
    assert len(settled) == 2 * 50 and settled.meta["samples_per_trajectory"] == 50
    np.testing.assert_allclose(settled.t, whole.t[tail], rtol=0, atol=1e-12)
    for key in ("q", "qd", "qdd", "p", "u"):
        np.testing.assert_allclose(getattr(settled, key), getattr(whole, key)[tail], atol=1e-9)
    assert settled.meta["simulation"]["settle"] == 0.5
    assert settled.meta["initial_states"] == whole.meta["initial_states"]
    assert make_dataset("task1", duration=1.0, **kw).meta["simulation"]["settle"] == 0.0


def test_settle_must_be_whole_samples():
    with pytest.raises(DataError, match=r"settle: 0.013 s is not a whole number of samples at 50"):
        datasets.plan_dataset("task1", settle=0.013, rate=50.0)
    with pytest.raises(DataError, match=r"settle: must be a non-negative"):
        datasets.plan_dataset("task1", settle=-1.0)


def test_rk4_dataset_and_resampling(cache):
    d = make_dataset(
        "task1", integrator="rk4", dt=0.001, rate=100.0, trajectories=2, duration=1.0, cache=cache
    )
    assert d.meta["simulation"]["integrator"] == "rk4"
    assert d.meta["simulation"]["dt"] == 0.001 and d.meta["simulation"]["substeps_per_sample"] == 10
    assert "rtol" not in d.meta["simulation"]
    r = resample(d, 20.0)
    assert len(r) == 2 * 20 and r.meta["rate"] == 20.0 and r.meta["resampled_from_rate"] == 100.0
    np.testing.assert_array_equal(r.q, d.q[np.r_[0:100:5, 100:200:5]])
    with pytest.raises(DataError, match="must divide"):
        resample(d, 30.0)
    with pytest.raises(DataError, match="must divide"):
        resample(d, 200.0)


def test_task5_fixed_step_defaults(cache):
    spec = load_spec("task5")
    cfg = data_config(spec)
    assert cfg.rates == (50.0, 100.0, 1000.0) and cfg.rate == 1000.0
    assert cfg.total_trajectories() == 12 and cfg.total_trajectories("rk4") == 5
    assert paper_splits(cfg, 12, "cvodes") == {
        "train": list(range(8)),
        "test": [8, 9, 10, 11],
        "blackbox_train": list(range(8)),
    }
    assert paper_splits(cfg, 5, "rk4") == {
        "train": [0, 1, 2],
        "test": [3, 4],
        "blackbox_train": [0, 1, 2],
    }


def test_paper_splits_task1():
    cfg = data_config(load_spec("task1"))
    total = cfg.total_trajectories()
    assert total == 84 + 5
    s = paper_splits(cfg, total, "cvodes")
    assert s["train"] == list(range(20)) and s["blackbox_train"] == list(range(84))
    assert s["test"] == list(range(84, 89))


def test_split_select_and_take(task4_data):
    d = copy.deepcopy(task4_data)
    d.meta["splits"] = {"train": [0, 1], "test": [2], "blackbox_train": [0, 1]}
    tr, te = split(d, "train"), split(d, "test")
    assert set(tr.traj) == {0, 1} and set(te.traj) == {2}
    assert len(tr) + len(te) == len(d)
    sel = select_trajectories(d, [2, 0], renumber=True)
    np.testing.assert_array_equal(sel.q[:100], d.q[200:])
    assert sel.meta["signals"][0] == d.meta["signals"][2]
    assert len(take_samples(d, 150)) == 150
    with pytest.raises(DataError, match=r"trajectories \[7\] are not in"):
        select_trajectories(d, [7])
    with pytest.raises(DataError, match="split: expected one of"):
        split(d, "validation")


def _spec(data_lines: str):
    text = (
        'name = "bad"\nkind = "mass-spring-damper"\nmasses = [1.0, 1.0]\nsprings = [1.0, 1.0]\n'
        "[data]\n" + data_lines
    )
    return spec_from_toml(text, source="bad.toml")


@pytest.mark.parametrize(
    "lines,match",
    [
        ("colour = 3\n", r"bad.toml: field 'data.colour': unknown key"),
        ("q0_low = [0.0]\nq0_high = [1.0]\n", r"'data.q0_low': expected 2 entries"),
        ("rates = [50.0, -1.0]\n", r"'data.rates': rates must be positive"),
        ("rate = 10.0\nrates = [5.0]\n", r"'data.rates': give either"),
        ("duration = -1.0\n", r"'data.duration': must be positive"),
        ("settle = -0.5\n", r"'data.settle': must not be negative"),
        ("integrator = 'euler'\n", r"'data.integrator': expected one of cvodes, rk4"),
        ("signal = 'square'\n", r"'data.signal': expected one of"),
        (
            "train_trajectories = 2.5\n",
            r"'data.train_trajectories': expected a non-negative integer",
        ),
        ("q0_low = [0.0, 0.0]\nq0_high = [1.0, -1.0]\n", r"'data.q0_high': must not be below"),
        ("q0_low = [0.0, 0.0]\n", r"'data.q0_high': give both"),
        ("q0_points = [[0.0, 0.0], [1.0]]\n", r"'data.q0_points': expected a list of rows of 2"),
        ("q0_points = [0.0, 0.0]\n", r"'data.q0_points': expected a list of rows of 2"),
        ("q0_points = []\n", r"'data.q0_points': expected a list of rows of 2"),
        ("q0_points = [[0.0, nan]]\n", r"'data.q0_points': expected a list of rows of 2"),
    ],
)
def test_bad_data_tables(lines, match):
    with pytest.raises(DataError, match=match):
        data_config(_spec(lines))


def test_q0_points_start_the_first_trajectories_and_change_nothing_else():
    base = data_config(_spec("q0_low = [-1.0, -1.0]\nq0_high = [1.0, 1.0]\nseed = 5\n"))
    points = data_config(
        _spec(
            "q0_low = [-1.0, -1.0]\nq0_high = [1.0, 1.0]\nseed = 5\n"
            "q0_points = [[2.5, -3.0], [0.25, 0.5]]\n"
        )
    )
    assert points.q0_points == ((2.5, -3.0), (0.25, 0.5))
    x0, sigs = datasets.draw_trajectories(base, 2, 0, range(4))
    y0, tigs = datasets.draw_trajectories(points, 2, 0, range(4))
    np.testing.assert_array_equal(y0[:2, :2], [[2.5, -3.0], [0.25, 0.5]])
    np.testing.assert_array_equal(y0[:2, 2:], x0[:2, 2:])  # velocities still drawn
    np.testing.assert_array_equal(y0[2:], x0[2:])  # the other trajectories unchanged
    assert [s.to_dict() for s in tigs] == [s.to_dict() for s in sigs]
    # a subset of ids: the points belong to trajectory ids, not rows
    z0, _ = datasets.draw_trajectories(points, 2, 0, [1, 3])
    np.testing.assert_array_equal(z0, y0[[1, 3]])


def test_every_preset_data_table_is_valid():
    from softpinn.symbolic.spec._spec import list_presets

    for name in list_presets():
        spec = load_spec(name)
        cfg = data_config(spec)
        assert cfg.duration > 0 and cfg.total_trajectories() >= 1


def test_write_refuses_existing_file(task4_data, tmp_path):
    path = write_dataset(tmp_path / "d.npz", task4_data)
    with pytest.raises(DataError, match="file exists .*--force"):
        write_dataset(path, task4_data)
    write_dataset(path, task4_data, force=True)
    with pytest.raises(DataError, match=r"must end in \.npz"):
        write_dataset(tmp_path / "d.csv", task4_data)
    with pytest.raises(DataError, match="no such file"):
        read_dataset(tmp_path / "missing.npz")


def test_virtual_machine_and_compiled_pipelines_agree(cache):
    c = make_dataset("task3", trajectories=1, duration=1.0, cache=cache)
    vm = make_dataset("task3", trajectories=1, duration=1.0, compile=False)
    assert c.meta["compiled"] and not vm.meta["compiled"]
    for key in ("q", "qd", "qdd", "p"):
        np.testing.assert_allclose(getattr(vm, key), getattr(c, key), rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(vm.u, c.u)
