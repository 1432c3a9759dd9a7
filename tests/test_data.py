"""Dataset loading, validation, trajectory split and pair construction (learn/_data.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from datagen import make_dataset, msd_matrices, simulate, write

from softpinn.errors import UserError
from softpinn.learn._data import load_dataset, make_pairs, mass_scale
from softpinn.learn._splits import split_trajectories


@pytest.fixture(scope="module")
def msd_file(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("data") / "msd.npz", trajectories=5, duration=2.0)


@pytest.fixture
def arrays():
    return simulate("msd", trajectories=3, duration=1.0)


def test_load_good_file(msd_file):
    ds = load_dataset(msd_file, n=2, m=1)
    assert ds.n == 2 and ds.m == 1
    assert ds.trajectory_ids.tolist() == [0, 1, 2, 3, 4]
    assert ds.meta["spec"]["name"] == "test-msd"
    assert len(ds.sha256) == 64
    # the analytic data obey eq. 25: M qdd + K q + B qd = A u
    M, K, B, A = msd_matrices()
    res = ds.qdd @ M.T + ds.q @ K.T + ds.qd @ B.T - ds.u @ A.T
    assert np.abs(res).max() < 1e-12
    np.testing.assert_allclose(ds.p, ds.qd @ M.T)


def test_pairs_stay_within_trajectories(msd_file):
    ds = load_dataset(msd_file)
    pairs = make_pairs(ds, [1, 3], state="velocity")
    per = (ds.traj == 1).sum() - 1 + (ds.traj == 3).sum() - 1
    assert pairs.count == per
    np.testing.assert_allclose(pairs.dt, 0.05)
    # x1 of each pair is the sample right after x0 in the same trajectory
    x = ds.state("velocity")
    for a, b in zip(pairs.x0, pairs.x1, strict=True):
        i = int(np.flatnonzero((x == a).all(axis=1))[0])
        assert ds.traj[i] == ds.traj[i + 1]
        np.testing.assert_array_equal(x[i + 1], b)
    assert pairs.xdot0.shape == (per, 4)
    first = np.concatenate([ds.indices(1)[:-1], ds.indices(3)[:-1]])
    np.testing.assert_array_equal(pairs.xdot0[:, 2:], ds.qdd[first])
    np.testing.assert_array_equal(pairs.xdot0[:, :2], ds.qd[first])
    mom = make_pairs(ds, [1], state="momentum")
    assert mom.xdot0 is None
    np.testing.assert_allclose(mom.x0[:, 2:], ds.p[ds.traj == 1][:-1])


def test_variable_step_dt(tmp_path, arrays):
    t = arrays["t"].copy()
    rng = np.random.default_rng(1)
    for j in range(3):
        rows = arrays["traj"] == j
        t[rows] = np.cumsum(rng.uniform(0.01, 0.1, rows.sum()))
    arrays["t"] = t
    ds = load_dataset(write(tmp_path / "v.npz", arrays))
    pairs = make_pairs(ds, [0, 1, 2])
    expect = np.concatenate([np.diff(t[arrays["traj"] == j]) for j in range(3)])
    np.testing.assert_allclose(pairs.dt, expect)


def test_subsampling_is_seeded(msd_file):
    ds = load_dataset(msd_file)
    a = make_pairs(ds, [0, 1, 2], samples=50, seed=3)
    b = make_pairs(ds, [0, 1, 2], samples=50, seed=3)
    c = make_pairs(ds, [0, 1, 2], samples=50, seed=4)
    assert a.count == 50
    np.testing.assert_array_equal(a.x0, b.x0)
    assert not np.array_equal(a.x0, c.x0)
    assert make_pairs(ds, [0], samples=10_000).count == (ds.traj == 0).sum() - 1


def test_split_by_trajectory(msd_file):
    ds = load_dataset(msd_file)
    tr, te = split_trajectories(ds, test=2, seed=0)
    assert len(te) == 2 and len(tr) == 3 and not set(tr) & set(te)
    tr2, te2 = split_trajectories(ds, test=2, seed=0)
    np.testing.assert_array_equal(te, te2)
    tr, te = split_trajectories(ds, test=[4])
    assert te.tolist() == [4] and tr.tolist() == [0, 1, 2, 3]
    tr, te = split_trajectories(ds, test=0.4, seed=1)
    assert len(te) == 2
    assert len(split_trajectories(ds)[1]) == 1
    with pytest.raises(UserError, match="not in"):
        split_trajectories(ds, test=[7])
    with pytest.raises(UserError, match="no trajectory"):
        split_trajectories(ds, test=[0, 1, 2, 3, 4])
    with pytest.raises(UserError, match="between 1 and 4"):
        split_trajectories(ds, test=5)


def _bad(tmp_path, arrays, **changes):
    a = dict(arrays)
    for k, v in changes.items():
        if v is None:
            a.pop(k)
        else:
            a[k] = v
    return write(tmp_path / "bad.npz", a)


def test_refuses_nan(tmp_path, arrays):
    q = arrays["q"].copy()
    q[5, 1] = np.nan
    path = _bad(tmp_path, arrays, q=q)
    msg = r"bad\.npz: 'q' holds 1 NaN/inf value\(s\), first at index \(5, 1\)"
    with pytest.raises(UserError, match=msg):
        load_dataset(path)
    u = arrays["u"].copy()
    u[0, 0] = np.inf
    with pytest.raises(UserError, match="'u' holds 1 NaN/inf"):
        load_dataset(_bad(tmp_path, arrays, u=u))


def test_refuses_shapes(tmp_path, arrays):
    with pytest.raises(UserError, match=r"'qd' must have shape \(\d+, 2\) like 'q'"):
        load_dataset(_bad(tmp_path, arrays, qd=arrays["qd"][:, :1]))
    with pytest.raises(UserError, match="'traj' must have shape"):
        load_dataset(_bad(tmp_path, arrays, traj=arrays["traj"][:-1]))
    with pytest.raises(UserError, match="'u' must have shape"):
        load_dataset(_bad(tmp_path, arrays, u=arrays["u"][:, 0]))


def test_refuses_time_order(tmp_path, arrays):
    t = arrays["t"].copy()
    t[7] = t[6]
    with pytest.raises(UserError, match=r"time must increase within a trajectory.*t\[7\]"):
        load_dataset(_bad(tmp_path, arrays, t=t))
    # time restarting at a new trajectory is fine
    assert load_dataset(_bad(tmp_path, arrays)).trajectory_ids.size == 3
    traj = arrays["traj"].copy()
    traj[3] = 2
    with pytest.raises(UserError, match="contiguous"):
        load_dataset(_bad(tmp_path, arrays, traj=traj))


def test_refuses_size_mismatch(msd_file):
    with pytest.raises(UserError, match=r"msd\.npz: model has n=3 coordinates, the file has n=2"):
        load_dataset(msd_file, n=3)
    with pytest.raises(UserError, match="model has m=2 inputs, the file has m=1"):
        load_dataset(msd_file, m=2)


def test_refuses_missing_key_and_bad_meta(tmp_path, arrays):
    with pytest.raises(UserError, match=r"bad\.npz: missing key\(s\) qdd"):
        load_dataset(_bad(tmp_path, arrays, qdd=None))
    with pytest.raises(UserError, match="no such file"):
        load_dataset(tmp_path / "nothing.npz")
    a = dict(arrays)
    np.savez(tmp_path / "m.npz", **a, meta=np.array("{not json"))
    with pytest.raises(UserError, match="'meta' must be a 0-d string of JSON"):
        load_dataset(tmp_path / "m.npz")
    (tmp_path / "junk.npz").write_text(json.dumps({"a": 1}))
    with pytest.raises(UserError, match="cannot be read"):
        load_dataset(tmp_path / "junk.npz")


def test_mass_scale_is_the_median_mass_or_inverse_mass(msd_file):
    """p = M q̇ with the constant diagonal M = diag(1.0, 1.8) of eq. 25: rms(p)/rms(q̇) is the
    mass of each coordinate exactly, the median of two is their mean."""
    data = load_dataset(msd_file)
    M = msd_matrices()[0]
    masses = np.diag(M)
    assert mass_scale(data, "lagrangian") == pytest.approx(np.median(masses), rel=1e-12)
    assert mass_scale(data, "hamiltonian") == pytest.approx(np.median(1 / masses), rel=1e-12)
    assert mass_scale(data, "hamiltonian", [0]) == pytest.approx(np.median(1 / masses), rel=1e-12)
    with pytest.raises(UserError, match="kind must be a physics model kind, got 'blackbox'"):
        mass_scale(data, "blackbox")


def _msd_at_rates(tmp_path, rates=(50.0, 100.0, 200.0)):
    """The mass-spring-damper's two trajectories of 2 s sampled at each rate, halving dt."""
    for rate in rates:
        yield load_dataset(make_dataset(tmp_path / f"msd{rate:g}.npz", trajectories=2,
                                        duration=2.0, rate=rate))


def _assert_second_order(errors):
    """Errors at halving dt fall by about 4 each time."""
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 1.8), (errors, orders)


def test_difference_accelerations_converge_at_second_order(tmp_path):
    """Central differences of q̇ against the recorded q̈: error O(dt²) inside and at the ends,
    never mixing two trajectories."""
    from softpinn.learn._data import difference_accelerations

    errors = []
    for data in _msd_at_rates(tmp_path):
        fd = difference_accelerations(data)
        errors.append(np.max(np.abs(fd - data.qdd)))
        # the pairs' ẋ carries the estimate; "recorded" keeps the file's q̈
        pairs = make_pairs(data, [0, 1], accel="differences")
        firsts = np.r_[data.indices(0)[:-1], data.indices(1)[:-1]]
        np.testing.assert_array_equal(pairs.xdot0[:, 2:], fd[firsts])
        np.testing.assert_array_equal(make_pairs(data, [0]).xdot0[:, 2:],
                                      data.qdd[data.indices(0)[:-1]])
    _assert_second_order(errors)


def test_difference_momenta_converge_at_second_order(tmp_path):
    """ṗ from central differences of p (eq. 10's labels on momentum data) against M q̈ (the
    mass-spring-damper's M is constant): error O(dt²); the pairs carry (q̇ recorded, ṗ)."""
    from softpinn.learn._data import difference_momenta

    M = msd_matrices()[0]
    errors = []
    for data in _msd_at_rates(tmp_path):
        fd = difference_momenta(data)
        errors.append(np.max(np.abs(fd - data.qdd @ M.T)))
        pairs = make_pairs(data, [0, 1], state="momentum", accel="differences")
        firsts = np.r_[data.indices(0)[:-1], data.indices(1)[:-1]]
        np.testing.assert_array_equal(pairs.xdot0, np.c_[data.qd, fd][firsts])
        assert make_pairs(data, [0], state="momentum").xdot0 is None
    _assert_second_order(errors)
    assert errors[-1] < 1e-3 * np.max(np.abs(data.qdd))
    with pytest.raises(UserError, match=r"accel labels must be one of \['recorded', 'diff"):
        make_pairs(data, [0], accel="smoothed")


def test_the_split_the_file_records_is_the_default(tmp_path, arrays):
    """A file's meta['splits']['test'] (simulate's spec, import --test-trajectories) holds those
    trajectories out when no split is given; a recorded split that is empty, holds every
    trajectory or names ids not in the file falls back to 20% at random."""
    meta = {"spec": {"name": "t"}, "splits": {"train": [0], "test": [1, 2]}}
    ds = load_dataset(write(tmp_path / "s.npz", arrays, meta))
    tr, te = split_trajectories(ds)
    assert tr.tolist() == [0] and te.tolist() == [1, 2]
    # given splits still win
    assert split_trajectories(ds, test=[0])[1].tolist() == [0]
    assert len(split_trajectories(ds, test=1, seed=0)[1]) == 1
    for bad in ([], [0, 1, 2], [1, 9], "2", None):
        meta = {"spec": {"name": "t"}, "splits": {"test": bad}}
        ds = load_dataset(write(tmp_path / "b.npz", arrays, meta))
        assert len(split_trajectories(ds, seed=0)[1]) == 1  # 20% of 3, at random


def test_both_sides_read_a_file_by_the_same_keys(tmp_path, arrays):
    """The dataset's keys live once (``softpinn.files``): symbolic and learn both require
    ``t, q, qd, qdd, u, traj, meta`` and both take ``p`` as optional (a recording has no
    momenta, docs/velocity.md); before, symbolic refused a file without ``p``."""
    from softpinn import files
    from softpinn.learn import _data
    from softpinn.symbolic import read_dataset, select_trajectories

    assert _data.REQUIRED_KEYS == files.DATASET_REQUIRED == (
        "t", "q", "qd", "qdd", "u", "traj", "meta")
    assert _data.OPTIONAL_KEYS == files.DATASET_OPTIONAL == ("p",)
    no_p = _bad(tmp_path, arrays, p=None)
    assert load_dataset(no_p).p is None
    sim = read_dataset(no_p)
    assert sim.p is None and "p" not in sim.arrays()
    assert select_trajectories(sim, [1]).p is None
    np.testing.assert_array_equal(read_dataset(_bad(tmp_path, arrays)).p, arrays["p"])
    no_qdd = _bad(tmp_path, arrays, qdd=None)
    with pytest.raises(UserError, match=r"missing key\(s\) qdd"):
        load_dataset(no_qdd)
    with pytest.raises(UserError, match=r"missing key\(s\) qdd"):
        read_dataset(no_qdd)
