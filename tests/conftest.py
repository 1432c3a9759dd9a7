"""Shared test setup: float64 JAX before any array exists, rank promotion an error, a headless
matplotlib, seeded keys."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# XLA's fast-compile settings (learn/xlaflags.py): the tests' tiny trainings spend most of their
# time compiling; the programs compute the same numbers (measured: training tests 35 % faster)
from softpinn.learn.xlaflags import with_fast_compile  # noqa: E402

os.environ["XLA_FLAGS"] = with_fast_compile(os.environ.get("XLA_FLAGS"))
# XLA's compiled programs shared by the test processes and kept for the next run, as the CLI
# does (learn/jitcache.py; SOFTPINN_JIT_CACHE=off runs the suite without)
from softpinn.learn.jitcache import enable_compile_cache  # noqa: E402

enable_compile_cache()

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# broadcasting arrays of different ranks is an error in the tests (as in diffrax and equinox):
# every broadcast in learn and bridge is written out
jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture
def ctrl_c_raises():
    """Ctrl-C raises KeyboardInterrupt in this test, as in a terminal, even where the process
    ignores SIGINT: pytest-xdist's workers do (their controller handles Ctrl-C), and so does a
    shell's background job (Python then keeps SIGINT ignored)."""
    import signal

    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.fixture
def getkey():
    """Return a function that gives a fresh, deterministic PRNG key on each call."""
    key = jax.random.PRNGKey(0)

    def _getkey():
        nonlocal key
        key, sub = jax.random.split(key)
        return sub

    return _getkey


#: The test suite runs the quick pipelines on even shorter budgets (the notebooks get the same
#: through SOFTPINN_EPOCHS / SOFTPINN_LBFGS, so that they reuse these runs).
QUICK_EPOCHS = 30


@pytest.fixture(scope="session")
def quick_runs(tmp_path_factory):
    """``get(task)`` runs ``reproduce(task, quick=True)`` once per session into a shared folder
    (``get.root``), so the pipeline tests and the notebooks reuse the same runs."""
    root = tmp_path_factory.mktemp("quick-runs")
    cache = {}

    def get(task):
        if task not in cache:
            from softpinn.bridge.app import reproduce
            from softpinn.bridge.tasks import ReproduceConfig

            # task 1 runs its two models side by side (--jobs 2): every test of its run
            # checks the parallel path's files; test_pipelines checks a serial call agrees
            config = ReproduceConfig(task, quick=True, epochs=QUICK_EPOCHS, lbfgs_steps=0,
                                     jobs=2 if task == "task1" else 1)
            cache[task] = reproduce(config, root / f"{task}-quick")
        return cache[task]

    get.root = root
    return get


@pytest.fixture
def session_cache(tmp_path_factory, monkeypatch):
    """Compiled libraries go to a cache of this test session, not the user's (the export and
    control tests: ``pytestmark = pytest.mark.usefixtures("session_cache")``)."""
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


@pytest.fixture(scope="session")
def msd_spec(tmp_path_factory):
    """Path of the forced two-mass chain's spec (datagen.MSD_SPEC): the model of the runs trained
    on ``make_dataset``'s "msd" data (export and control tests)."""
    from datagen import MSD_SPEC

    path = tmp_path_factory.mktemp("spec") / "forced.toml"
    path.write_text(MSD_SPEC)
    return str(path)


@pytest.fixture(scope="session")
def msd_full_spec(tmp_path_factory):
    """Path of the same chain with a force on each mass (datagen.MSD_SPEC_FULL)."""
    from datagen import MSD_SPEC_FULL

    path = tmp_path_factory.mktemp("spec") / "full.toml"
    path.write_text(MSD_SPEC_FULL)
    return str(path)
