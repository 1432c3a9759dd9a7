"""Input signals: symbolic and numpy faces agree, round-trip through dicts, seeded sampling."""

from __future__ import annotations

import json

import casadi as ca
import numpy as np
import pytest

from softpinn.errors import UserError
from softpinn.symbolic.simulation._signals import (
    KINDS,
    Chirp,
    Multisine,
    Sinusoid,
    Step,
    Zero,
    sample_signal,
    signal_from_dict,
)

EXAMPLES = [
    Zero(2),
    Sinusoid([1.0, 0.5], [0.3, 1.2], [0.0, 1.0], [0.2, -0.1]),
    Multisine([[1.0, 0.2], [0.5, 0.1]], [[0.3, 1.0], [2.0, 0.4]], [[0, 1], [2, 3]], [0.1, 0.0]),
    Step(times=[0.5, 1.5], levels=[[0.0, 1.0], [2.0, -1.0], [1.0, 0.5]]),
    Chirp([1.0, 2.0], [0.1, 0.2], [2.0, 1.0], 3.0, [0.0, 0.5], [0.0, 1.0]),
]


@pytest.mark.parametrize("sig", EXAMPLES, ids=lambda s: s.kind)
def test_symbolic_equals_numeric(sig):
    t = np.linspace(0.0, 3.0, 61) + 0.013  # avoid sampling exactly on a step
    f = sig.function()
    sym = np.asarray(f.map(len(t))(t[None, :], np.tile(sig.params()[:, None], len(t)))).T
    np.testing.assert_allclose(sym, sig(t), rtol=1e-14, atol=1e-14)
    assert sig(t).shape == (len(t), sig.m)


@pytest.mark.parametrize("sig", EXAMPLES, ids=lambda s: s.kind)
def test_dict_round_trip(sig):
    d = json.loads(json.dumps(sig.to_dict()))
    assert d["kind"] == sig.kind
    back = signal_from_dict(d)
    assert back == sig
    assert back.structure() == sig.structure()


def test_sinusoid_formula():
    s = Sinusoid([2.0], [0.5], [0.25], [1.0])
    t = np.array([0.0, 0.3, 1.7])
    np.testing.assert_allclose(s(t)[:, 0], 1.0 + 2.0 * np.sin(2 * np.pi * 0.5 * t + 0.25))


def test_chirp_instantaneous_frequency_sweeps():
    s = Chirp([1.0], [0.5], [5.0], 10.0, [0.0], [0.0])
    # phase derivative / 2 pi goes linearly from f0 to f1
    t = ca.MX.sym("t")
    ph = 2 * np.pi * (0.5 * t + (5.0 - 0.5) * t**2 / 20.0)
    dph = ca.Function("d", [t], [ca.jacobian(ph, t)])
    assert abs(float(dph(0.0)) / (2 * np.pi) - 0.5) < 1e-12
    assert abs(float(dph(10.0)) / (2 * np.pi) - 5.0) < 1e-12
    tt = np.linspace(0, 10, 7)
    np.testing.assert_allclose(s(tt)[:, 0], np.sin(2 * np.pi * (0.5 * tt + 4.5 * tt**2 / 20)))


def test_step_levels():
    s = EXAMPLES[3]
    np.testing.assert_array_equal(
        s(np.array([0.0, 0.49, 0.5, 1.0, 1.5, 9.0])),
        [[0, 1], [0, 1], [2, -1], [2, -1], [1, 0.5], [1, 0.5]],
    )


def test_sampling_is_seeded_and_in_range():
    ranges = {
        "amplitude_low": [0.2, 0.2, 0.2],
        "amplitude_high": [1.5, 1.5, 1.5],
        "offset_low": [-0.5, -0.5, 0.0],
        "offset_high": [0.5, 0.5, 1.5],
        "frequency_low": 0.1,
        "frequency_high": 1.0,
    }
    a = [sample_signal("sinusoid", 3, np.random.default_rng(7), ranges) for _ in range(2)]
    assert a[0] == a[1]
    b = sample_signal("sinusoid", 3, np.random.default_rng(8), ranges)
    assert b != a[0]
    many = [sample_signal("sinusoid", 3, np.random.default_rng(i), ranges) for i in range(50)]
    amp = np.array([s.amplitude for s in many])
    off = np.array([s.offset for s in many])
    assert amp.min() >= 0.2 and amp.max() <= 1.5
    assert off[:, 2].min() >= 0.0 and off[:, 2].max() <= 1.5
    for kind in KINDS:
        s = sample_signal(kind, 3, np.random.default_rng(0), ranges, duration=5.0)
        assert s.kind == kind and s.m == 3
    assert sample_signal("sinusoid", 0, np.random.default_rng(0)) == Zero(0)


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda: Sinusoid([1.0, 2.0], [0.1, 0.2, 0.3], [0.0, 0.0], [0.0, 0.0]), "expected 2"),
        (lambda: Step(times=[2.0, 1.0], levels=[[0.0], [1.0], [2.0]]), "increasing"),
        (lambda: Chirp([1.0], [0.1], [1.0], -1.0, [0.0], [0.0]), "sweep_time"),
        (lambda: sample_signal("square", 2, np.random.default_rng(0)), "expected one of"),
        (
            lambda: sample_signal(
                "sinusoid",
                2,
                np.random.default_rng(0),
                {"amplitude_low": [1.0, 1.0], "amplitude_high": [0.5, 2.0]},
            ),
            "amplitude_high",
        ),
        (lambda: signal_from_dict({"kind": "sinusoid", "amplitude": [1.0]}), "sinusoid"),
    ],
)
def test_bad_signals(make, match):
    with pytest.raises(UserError, match=match):
        make()
