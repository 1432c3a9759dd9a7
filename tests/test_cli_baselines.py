"""The baselines inside the tool (issue 43): ``predict`` at several horizons in one call, the
baselines and the verdict line beside a network, and ``train --model linear`` end to end."""

from __future__ import annotations

import json
import re
import shutil

import pytest
from datagen import make_dataset

from softpinn.bridge.cli import main
from softpinn.learn import load_dataset

# the same settings as tests/test_cli_learn.py, so the program compiles once
TRAIN = [
    "--model", "blackbox", "--hidden", "16", "2", "--epochs", "12", "--batch-size", "64",
    "--lr", "1e-2", "--test-trajectories", "4", "--checkpoint-every", "1000", "--quiet",
]  # fmt: skip
OLD_KEYS = {"one_step_error", "rollout_error_mean", "rollout_error_std", "rollout_errors",
            "rollout_diverged", "horizon", "reset_every", "dt", "trajectories", "plot", "run",
            "seed", "model", "dataset", "split"}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    # a linear system (the two-mass spring-damper): the linear second-order model is exact
    return make_dataset(tmp_path_factory.mktemp("bl") / "msd.npz", trajectories=5, duration=4.0)


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("bl") / "run"
    assert main(["train", str(data), "--out", str(out), *TRAIN]) == 0
    return out


@pytest.fixture(scope="module")
def linear(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("bl") / "linear"
    assert main(["train", str(data), "--model", "linear", "--out", str(out),
                 "--test-trajectories", "4"]) == 0
    return out


def _json(capsys, args):
    capsys.readouterr()
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)


def _error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("softpinn: error: ")
    return err[0]


@pytest.mark.parametrize("extra", [[], ["--reset-every", "0.5"], ["--dt", "0.025"]])
def test_several_horizons_in_one_call_equal_separate_calls(run, data, capsys, extra):
    base = ["predict", str(run), str(data), *extra, "--json", "--no-baselines"]
    many = _json(capsys, [*base[:3], "--horizon", "3", "0.5", "1.5", *base[3:]])
    assert many["horizons"] == [0.5, 1.5, 3.0] and "baselines" not in many
    for h, got in zip(many["horizons"], many["results"], strict=True):
        one = _json(capsys, [*base[:3], "--horizon", str(h), *base[3:]])
        assert set(one) == OLD_KEYS  # --no-baselines: exactly the object of one horizon
        assert got["horizon"] == h
        assert got == one  # the same numbers, to the last bit


def test_predict_text_one_line_per_horizon_baselines_and_verdict(run, data, capsys, tmp_path):
    capsys.readouterr()
    png = tmp_path / "p.png"
    assert main(["predict", str(run), str(data), "--horizon", "1", "3", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert sum(line.startswith("rollout error (") for line in lines) == 2
    assert "rollout error (1 s): " in out and "rollout error (3 s): " in out
    assert "baselines (fitted on the run's training trajectories 0, 1, 2, 3):" in out
    assert any(line.strip().startswith("1 s: no motion ") for line in lines)
    verdict = [line for line in lines if line.startswith("verdict: ")]
    # data of a linear system and a 12-epoch network: the linear model wins at both horizons
    assert len(verdict) == 1
    assert "at 1 s LOSES to linear 2nd order" in verdict[0], verdict
    assert "at 3 s LOSES to linear 2nd order" in verdict[0], verdict
    assert f"plot: {png} (the 3 s rollout)" in out and png.is_file()


def test_predict_json_has_the_baselines_and_verdict(run, data, capsys):
    one = _json(capsys, ["predict", str(run), str(data), "--horizon", "2", "--json"])
    assert set(one) == OLD_KEYS | {"baselines", "verdict"}
    bl = one["baselines"]
    assert bl["train_trajectories"] == [0, 1, 2, 3] and bl["test_trajectories"] == [4]
    assert {s["name"] for s in bl["scores"]} == {"no motion", "ARX (order 2)",
                                                 "lagged ARX",
                                                 "linear 2nd order",
                                                 "linear 2nd order, rollout fit"}
    assert one["verdict"].startswith("blackbox network: at 2 s ")
    many = _json(capsys, ["predict", str(run), str(data), "--horizon", "1", "2", "--json"])
    assert [r["horizon"] for r in many["results"]] == [1.0, 2.0]
    assert {s["horizon"] for s in many["baselines"]["scores"]} == {1.0, 2.0}
    assert many["verdict"].count(" LOSES to ") + many["verdict"].count(" beats ") == 2


def test_predict_keeps_the_fitted_baselines_in_the_run_and_reads_them_back(run, data, capsys,
                                                                            monkeypatch):
    import softpinn.bridge.analysis.baselines as bl

    cache = run / "baselines.json"
    cache.unlink(missing_ok=True)
    args = ["predict", str(run), str(data), "--horizon", "2", "--json"]
    first = _json(capsys, args)
    doc = json.loads(cache.read_text())
    assert [e["name"] for e in doc["models"]] == [name for name, _, _ in bl.BASELINES]
    assert doc["train_trajectories"] == [0, 1, 2, 3] and len(doc["key"]) == 64

    def no_fit(*a, **k):
        raise AssertionError("refitted although the cache holds the same fits")

    monkeypatch.setattr(bl, "fit_baseline", no_fit)
    assert _json(capsys, args)["baselines"] == first["baselines"]  # the same numbers, read back
    monkeypatch.undo()
    cache.write_text("{not json")  # a broken cache refits, and is written whole again
    assert _json(capsys, args)["baselines"] == first["baselines"]
    assert json.loads(cache.read_text())["key"] == doc["key"]
    # another input hold or other training rows are other fits: not read from the cache
    loaded = load_dataset(data)
    assert bl._fit_key(loaded, [0, 1, 2, 3], "constant") == doc["key"]
    assert bl._fit_key(loaded, [0, 1, 2, 3], "linear") != doc["key"]
    assert bl._fit_key(loaded, [0, 1, 2], "constant") != doc["key"]


def test_train_linear_and_predict_end_to_end(linear, data, capsys):
    for name in ("config.json", "metrics.json", "arx.json", "arx_lags.json", "linear2.json",
                 "linear2_rollout.json", "no_motion.json"):
        assert (linear / name).is_file(), name
    cfg = json.loads((linear / "config.json").read_text())
    assert cfg["model"]["kind"] == "linear" and cfg["split"] == {"train": [0, 1, 2, 3],
                                                                 "test": [4]}
    metrics = json.loads((linear / "metrics.json").read_text())
    assert metrics["arx"]["one_step_rms"] > 0 and metrics["linear2"]["accel_rms"] >= 0
    oe = metrics["linear2_rollout"]  # the rollout fit starts at least squares, never worse
    assert oe["fit"] == "rollout" and oe["rollout_error"] <= oe["least_squares_rollout_error"]
    assert json.loads((linear / "arx.json").read_text())["order"] == 2
    capsys.readouterr()
    assert main(["predict", str(linear), str(data), "--horizon", "1", "3"]) == 0
    out = capsys.readouterr().out
    assert "rollout error over trajectory 4" in out
    assert "  1 s: no motion " in out and "  3 s: no motion " in out
    # a linear system: one of the second-order fits is best, or the lagged ARX, which holds
    # its exact discretisation (two lags of q and of u)
    assert re.search(r"best: (linear 2nd order(, rollout fit)?|lagged ARX) at every horizon",
                     out), out
    doc = _json(capsys, ["predict", str(linear), str(data), "--horizon", "1", "--json",
                         "--trajectories", "all"])
    assert doc["best"][0].startswith("linear 2nd order") and doc["trajectories"] == [0, 1, 2,
                                                                                   3, 4]


def test_a_linear_run_from_before_the_rollout_fit_still_predicts(linear, data, capsys,
                                                                  tmp_path):
    old = tmp_path / "old"
    shutil.copytree(linear, old)
    (old / "linear2_rollout.json").unlink()
    (old / "arx_lags.json").unlink()
    cfg = json.loads((old / "config.json").read_text())
    for key in ("files", "names"):
        del cfg["model"][key]["linear2_rollout"]
        del cfg["model"][key]["arx_lags"]
    (old / "config.json").write_text(json.dumps(cfg))
    doc = _json(capsys, ["predict", str(old), str(data), "--horizon", "1", "--json"])
    assert {s["kind"] for s in doc["baselines"]["scores"]} == {"no_motion", "arx", "linear2"}


def test_linear_refusals_are_one_line(linear, data, tmp_path, capsys):
    capsys.readouterr()
    for flag in (["--epochs", "3"], ["--hidden", "8", "2"], ["--lr", "0.1"]):
        assert main(["train", str(data), "--model", "linear", "--out", str(tmp_path / "x"),
                     *flag]) == 2
        assert f"{flag[0]} applies to network models, not --model linear" in _error_line(capsys)
    for args in (["analyze", str(linear), "task4", "--out", str(tmp_path / "a")],
                 ["export", str(linear), "--out", str(tmp_path / "e")]):
        assert main(args) == 2
        assert "a linear baseline run has no learned matrices; " in _error_line(capsys)
    assert main(["predict", str(linear), str(data), "--horizon", "1", "--dt", "0.01"]) == 2
    assert "--dt applies to a network's run" in _error_line(capsys)
    assert main(["train", str(data), "--model", "linear", "--out", str(linear)]) == 2
    assert "already exists and is not empty; use --force" in _error_line(capsys)
    assert main(["predict", str(linear), str(data), "--horizon", "0"]) == 2
    assert "horizon: expected a positive number of seconds" in _error_line(capsys)
