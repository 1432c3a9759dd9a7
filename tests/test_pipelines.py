"""The paper tasks 1-3 end to end on quick settings, the reproduce/analyze CLI, and their
notebooks (and the control notebook, on task 3's runs) executed on the same runs. Tasks 4 and 5
are in test_pipelines_task45.py with the same checks: the suite's xdist workers take whole
modules, so the two modules run side by side, each on its worker's own quick runs."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import nbformat
import numpy as np
import pytest
from conftest import QUICK_EPOCHS
from nbclient import NotebookClient

from softpinn.bridge.app import reproduce
from softpinn.bridge.cli import main
from softpinn.bridge.tasks import TASKS, ReproduceConfig, make_plan, variant_model
from softpinn.symbolic.spec._spec import load_spec

pytestmark = pytest.mark.timeout(900)

EXPECTED_MODELS = {
    "task1": {"main": {"lagrangian", "blackbox"}},
    "task2": {"main": {"lagrangian", "blackbox"}},
    "task3": {"main": {"hamiltonian", "blackbox"}},
    "task4": {"main": {"lagrangian", "hamiltonian", "blackbox"}},
    "task5": {
        "fixed_0.0002s": {"lagrangian", "blackbox"},
        "50Hz": {"lagrangian"},
        "100Hz": {"lagrangian", "blackbox"},
    },
}


#: the tasks of this module (tasks 4 and 5: test_pipelines_task45.py)
HERE = ("task1", "task2", "task3")


@pytest.mark.parametrize("task", HERE)
def test_quick_pipeline_writes_report_tables_and_figures(task, quick_runs):
    check_quick_pipeline(task, quick_runs)


def check_quick_pipeline(task, quick_runs):
    """Run (or reuse) ``reproduce task --quick`` and check its report, tables and figures."""
    result = quick_runs(task)
    out = result.out_dir
    text = result.report.read_text()
    assert "Table III" in text and "| paper |" in text and "| ours |" in text
    assert "Floor of the one-step loss" in text and "Every model is integrated by RK4" in text
    assert "no forces" in text
    assert "Time scales: eigenvalues" in text and "| true |" in text
    # residuals at each of the paper's configurations, then over the sampled ones
    assert "Relative residual per configuration" in text and "| sampled (" in text
    # one way of writing residuals (percent), and a word for what each total means
    summary = re.search(r"\| total \| match \|.*?\n\n", text, re.S).group(0)
    rows = [r for r in summary.splitlines()[2:] if r.startswith("| ")]
    assert rows and all(r.split(" | ")[5].endswith(" %") for r in rows)
    words = {r.split(" | ")[6] for r in rows}
    assert words <= {"recovered", "approximate", "not recovered", "undefined"}
    assert "success" not in text
    assert "Force terms along" in text and "| A u − G − D q̇ |" in text
    assert "Acceleration terms" in text and "| M⁻¹(A u − G − D q̇) |" in text
    variants = result.results["variants"]
    # the training data's excitation of the true M's directions, once per data set
    assert text.count("**What the training data show of the inertia.**") == len(variants)
    if task == "task2":  # an undamped pendulum: no damping force to weigh the inertia against
        assert "The true model has no damping" in text
    else:
        assert "| direction | mostly | M eigenvalue | corner [Hz] |" in text
    assert {v: set(r["models"]) for v, r in variants.items()} == EXPECTED_MODELS[task]
    for vname, vres in variants.items():
        for kind, entry in vres["models"].items():
            pr = entry["predict"]
            for key in ("train_error", "test_error"):
                assert math.isfinite(pr[key]["mean"]), (vname, kind, key)
            # on the tests' tiny budgets a rollout may blow up: reported as inf, never NaN
            assert not math.isnan(pr["prediction_error"]["mean"]), (vname, kind)
            assert (out / "train" / vname / kind / "done.json").is_file()
            floor = entry["floor"]  # the true model stepped as this model is
            assert floor["pairs"] > 0 and not math.isnan(floor["mean"])
            assert floor["no_forces"] > 0  # the loss of a model that learned no forces
            assert floor["state"] == ("momentum" if kind == "hamiltonian" else "velocity")
            modes = entry["modes"]  # linearised at rest: 2n eigenvalues of each side
            assert len(modes["true"]) == len(modes["learned"]) == 2 * len(modes["q"])
            assert math.isfinite(modes["true_max_real"])
            if task == "task1":  # linear and damped: the same decaying modes everywhere
                assert modes["true_max_real"] < 0
            if kind != "blackbox":
                summary = entry["analyze"]["summary"]
                assert "pointwise" in summary
                # the pointwise P(q) = M M̂^-1 explains M exactly, by construction
                if kind == "lagrangian":
                    assert summary["pointwise"]["residual"]["M"] < 1e-8
                else:
                    assert "direct" in summary
                assert (out / "analyze" / vname / kind / "report.md").is_file()
                # the force terms along the model's own training trajectories
                an = json.loads((out / "analyze" / vname / kind / "analysis.json").read_text())
                forces = an["forces"]
                assert forces["samples"] > 0 and math.isfinite(forces["error"]["G"])
                trained = json.loads(
                    (out / "train" / vname / kind / "run" / "config.json").read_text())
                assert forces["meta"]["trajectories"] == trained["split"]["train"]
                accel = an["accelerations"]  # M^-1 times each, at the same samples
                assert accel["samples"] == forces["samples"]
                assert math.isfinite(accel["error"]["net"])
    assert list((out / "tables").glob("table_iii_*.csv"))
    figures = {p.name for p in (out / "figures").glob("*.png")}
    assert any(f.startswith("loss_") for f in figures)
    assert any(f.startswith("rollout_main_") for f in figures)
    assert any(f.startswith("rollout_other_") for f in figures)
    if task == "task5":
        assert "error_vs_rate.png" in figures
    for link in __import__("re").findall(r"\]\(([^)]+\.(?:png|md))\)", text):
        assert (out / link).is_file(), link
    saved = json.loads((out / "results.json").read_text())
    assert saved["task"] == task and saved["quick"] is True
    _baselines_beside_the_networks(result, text, saved)
    if task == "task3":
        _errors_are_reported_at_lambda_one(result, text)


def _baselines_beside_the_networks(result, text, saved):
    """Issue 43: every data set's networks beside no motion and the linear models, at the
    predict stage's horizons, with one verdict line per network; results.json keeps them."""
    for vname, vres in saved["results"]["variants"].items():
        bl = vres["baselines"]
        files = saved["results"]["data"]["variants"][vname]["physics"]
        assert bl["train_trajectories"] == files["train"]
        assert bl["test_trajectories"] == files["test"]
        models = vres["models"]
        pr = next(iter(models.values()))["predict"]
        horizons = {pr["prediction_error"]["horizon_s"], pr["long_prediction_error"]["horizon_s"]}
        assert sorted(horizons) == bl["horizons"]
        assert {(s["kind"], s["horizon"]) for s in bl["scores"]} == {
            (k, h) for k in ("no_motion", "arx", "arx_lags", "linear2", "linear2_rollout")
            for h in horizons}
        for s in bl["scores"]:
            assert s["mean"] is None or s["mean"] >= 0
        assert (result.out_dir / "baselines" / vname / "done.json").is_file()
        assert (result.out_dir / "tables" / f"baselines_{vname}.csv").is_file()
    table = re.findall(r"\| model \| rollout error over .*?\n\n", text, re.S)
    assert len(table) == len(saved["results"]["variants"])
    for t in table:
        assert "| no motion |" in t and "| ARX (order 2) |" in t and "| linear 2nd order |" in t
    for vres in saved["results"]["variants"].values():
        for kind in vres["models"]:
            who = "black box" if kind == "blackbox" else f"{kind.capitalize()} network"
            assert f"| {who} |" in text
            assert re.search(rf"^- {who}: at [0-9.]+ s (beats|LOSES)", text, re.M), who
    verdicts = re.findall(r"^- .*?: at [0-9.]+ s (?:beats|LOSES)", text, re.M)
    assert len(verdicts) == sum(len(v["models"]) for v in saved["results"]["variants"].values())


def _errors_are_reported_at_lambda_one(result, text):
    """Task 3's Hamiltonian network trains with λ = 0.1; its reported errors use λ = 1."""
    from softpinn.learn._data import load_dataset
    from softpinn.learn._predict import evaluate
    from softpinn.learn._train import load_run

    entry = result.results["variants"]["main"]["models"]["hamiltonian"]
    assert entry["train"]["config"]["loss_weight"] == 0.1
    assert "Hamiltonian network trains with λ = 0.1 in eq. 9" in text
    f = result.results["data"]["variants"]["main"]["physics"]
    run, data = load_run(entry["train"]["run"]), load_dataset(f["path"])
    test = {w: evaluate(run.model, data, f["test"], horizon=0.1, loss_weight=w,
                        input_hold="linear").one_step_error["mean"] for w in (0.1, 1.0)}
    assert entry["predict"]["test_error"]["mean"] == pytest.approx(test[1.0], rel=1e-9)
    assert test[0.1] < 0.5 * test[1.0]  # the weight matters: the p part is most of the loss


def test_second_call_skips_finished_stages(quick_runs):
    """Task 1's quick run trained its models side by side (--jobs 2, conftest): a serial call
    finds every stage finished with the same settings and gathers the same results."""
    import dataclasses

    first = quick_runs("task1")
    assert first.config.jobs == 2 and "2 models at a time (`--jobs 2`)" in first.report.read_text()
    done = sorted(first.out_dir.glob("**/done.json"))
    stamps = [p.stat().st_mtime_ns for p in done]
    lines = []
    again = reproduce(dataclasses.replace(first.config, jobs=1), first.out_dir, log=lines.append)
    assert [p.stat().st_mtime_ns for p in done] == stamps
    assert sum("skipped" in line for line in lines) == len(done)
    assert "[baselines/main] done before, skipped" in lines  # issue 43's stage is reused
    assert again.results["variants"]["main"]["baselines"] == (
        first.results["variants"]["main"]["baselines"])
    for kind in ("lagrangian", "blackbox"):
        a, b = (r.results["variants"]["main"]["models"][kind] for r in (first, again))
        assert a == b, kind
    # the figures were a stage of the workers' (drawn once the models were done); one that
    # is gone is drawn again, with the same report
    assert (first.out_dir / "draw" / "main" / "done.json") in done
    loss = first.out_dir / "figures" / "loss_main.png"
    loss.unlink()
    lines = []
    reproduce(dataclasses.replace(first.config, jobs=1), first.out_dir, log=lines.append)
    assert loss.is_file() and "[draw/main] ..." in lines
    assert sum("skipped" in line for line in lines) == len(done) - 1


def test_a_moved_output_folder_keeps_its_finished_stages(quick_runs, tmp_path, monkeypatch):
    """Stage records name paths inside the output folder as $OUT/...: a copy of the folder,
    reached by a relative path from another working directory, reuses every stage and its
    report links only files inside it (before, it linked the old folder's files, and the
    sections read from them went missing)."""
    import shutil

    first = quick_runs("task1")
    moved = tmp_path / "elsewhere" / "t1"
    shutil.copytree(first.out_dir, moved)
    done = sorted(moved.glob("**/done.json"))
    assert all(str(first.out_dir) not in p.read_text() for p in done)
    assert any("$OUT/data/" in p.read_text() for p in done)
    monkeypatch.chdir(tmp_path)
    lines = []
    again = reproduce(first.config, Path("elsewhere") / "t1", log=lines.append)
    assert sum("skipped" in line for line in lines) == len(done)
    text = again.report.read_text()
    assert "Acceleration terms" in text and "](../" not in text
    files = again.results["data"]["variants"]["main"]["physics"]
    assert Path(files["path"]).resolve().is_relative_to(moved.resolve())
    assert "elsewhere" in again.results["variants"]["main"]["models"]["lagrangian"]["train"]["run"]


def test_changed_training_settings_retrain_from_scratch(quick_runs, tmp_path):
    """A run folder trained on other settings is not resumed: the new budget is trained."""
    import dataclasses
    import shutil

    first = quick_runs("task1")
    out = tmp_path / "task1"
    shutil.copytree(first.out_dir, out)
    epochs = first.config.epochs + 3
    again = reproduce(dataclasses.replace(first.config, epochs=epochs, jobs=1), out,
                      log=lambda _: None)
    for kind in ("lagrangian", "blackbox"):
        metrics = again.results["variants"]["main"]["models"][kind]["train"]["metrics"]
        assert [m["epochs_run"] for m in metrics["members"]] == [epochs]


def test_new_data_retrain_every_model(quick_runs, tmp_path, monkeypatch):
    """Data simulated again (other settings, same file names) leave no model of the old data."""
    import dataclasses
    import shutil

    import softpinn.bridge.tasks.pipeline as pipelines

    first = quick_runs("task1")
    out = tmp_path / "task1"
    shutil.copytree(first.out_dir, out)
    plan = pipelines.make_plan
    monkeypatch.setattr(pipelines, "make_plan", lambda spec, config: dataclasses.replace(
        plan(spec, config), data={**plan(spec, config).data, "seed": 12345}))
    # serial: the patched plan lives in this process only, not in --jobs workers
    again = reproduce(dataclasses.replace(first.config, jobs=1), out, log=lambda _: None)
    for kind in ("lagrangian", "blackbox"):
        old = first.results["variants"]["main"]["models"][kind]["train"]["metrics"]
        new = again.results["variants"]["main"]["models"][kind]["train"]["metrics"]
        assert new["best_test_loss"]["mean"] != old["best_test_loss"]["mean"], kind


def test_seeds_report_mean_and_std_of_errors_and_matrices(tmp_path):
    """--seeds K: every seed is trained, predicted and analysed; the report gives the first
    seed's residual per configuration, then mean ± std (largest) over the seeds. With --jobs 2
    the numbers are the same."""
    import dataclasses

    result = reproduce(ReproduceConfig("task1", quick=True, seeds=2, epochs=10, lbfgs_steps=0),
                       tmp_path / "t1", log=lambda _: None)
    entry = result.results["variants"]["main"]["models"]["lagrangian"]
    assert set(entry["predict"]["prediction_error"]["seeds"]) == {"mean", "std"}
    seeds = entry["analyze"]["seeds"]
    assert [s["seed"] for s in seeds] == [0, 1]
    runs = [json.loads(Path(s["analysis"]).read_text()) for s in seeds]
    assert runs[0]["q"] == runs[1]["q"]  # the same configurations for every seed
    first = [r["transforms"]["alpha"]["residuals"]["M"][0] for r in runs]
    assert first[0] != first[1]  # two networks, two analyses
    text = result.report.read_text()
    assert "The same over all 2 seeds: mean ± std (largest)." in text
    mean, std, top = np.mean(first), np.std(first), np.max(first)
    assert f"{100 * mean:.2f} ± {100 * std:.2f} % ({100 * top:.2f} %)" in text
    # the same run with its two models side by side (--jobs 2) gives the same numbers
    side = reproduce(dataclasses.replace(result.config, jobs=2), tmp_path / "t1-jobs",
                     log=lambda _: None)
    assert _numbers(side.results, side.out_dir) == _numbers(result.results, result.out_dir)


def _numbers(results: dict, root: Path):
    """``results`` without times, its paths relative to ``root``."""
    if isinstance(results, dict):
        return {k: _numbers(v, root) for k, v in results.items() if "seconds" not in k}
    if isinstance(results, list):
        return [_numbers(v, root) for v in results]
    if isinstance(results, str):
        return results.replace(str(root), "$OUT")
    return results


def test_plans_follow_the_paper():
    full = {t: make_plan(load_spec(t), ReproduceConfig(t)) for t in TASKS}
    assert full["task1"].horizon == 2.7 and full["task3"].horizon == 5.0
    assert full["task5"].horizon == 10.0
    assert [v.name for v in full["task5"].variants] == [
        "fixed_0.0002s", "50Hz", "100Hz", "1000Hz"]
    assert full["task4"].models["lagrangian"].mass == (32, 3)  # Table III: 30*3, widened
    # every model of a task steps alike; task2's 0.08 s step needs RK4 sub-steps, the
    # actuated tasks' inputs are interpolated
    for t, (sub, hold) in {"task1": (1, "constant"), "task2": (2, "constant"),
                           "task3": (1, "linear"), "task5": (1, "linear")}.items():
        assert {(m.substeps, m.input_hold) for m in full[t].models.values()} == {(sub, hold)}
    # task5's 50 and 100 Hz steps exceed RK4's stable step for its fast mode: own sub-steps
    t5 = full["task5"]
    assert {v.name: v.substeps for v in t5.variants} == {
        "fixed_0.0002s": None, "50Hz": 3, "100Hz": 2, "1000Hz": None}
    assert [variant_model(t5, v, "lagrangian").substeps for v in t5.variants] == [
        1, 3, 2, 1]
    assert t5.models["lagrangian"].substeps == 1
    # its black box steps each 10 ms pair in one (its own max_step, as the paper steps pairs)
    assert [variant_model(t5, v, "blackbox").substeps for v in t5.variants
            if "blackbox" in v.models] == [1, 1]
    # as many optimizer steps on the 50 Hz data's 23,992 pairs as on 45,000 elsewhere
    fifty = next(v for v in t5.variants if v.name == "50Hz")
    files = {"physics": {"samples": 23992}}
    assert variant_model(t5, fifty, "lagrangian", files).epochs == 376
    assert variant_model(t5, fifty, "lagrangian", {"physics": {"samples": 48000}}).epochs == 200
    assert "equal_steps" not in variant_model(t5, fifty, "lagrangian", files).to_dict()
    assert variant_model(t5, fifty, "blackbox", files).epochs == 40
    fixed = make_plan(load_spec("task5"), ReproduceConfig("task5", epochs=7))
    assert variant_model(fixed, fifty, "lagrangian", files).epochs == 7
    assert t5.models["lagrangian"].lr == 1e-2 and t5.models["blackbox"].lr == 2e-3
    # task5's Lagrangian networks learn from eq. 10 with q̈ from differences of the velocities
    assert (t5.models["lagrangian"].loss, t5.models["lagrangian"].accel_labels) == (
        "accel", "differences")
    assert {m.trained_with("loss") for t in TASKS for k, m in full[t].models.items()
            if (t, k) != ("task5", "lagrangian")} == {"pair"}
    # task3's Hamiltonian network weighs q and p alike (λ = 0.1); every other model λ = 1
    assert {(t, k): m.loss_weight for t in TASKS for k, m in full[t].models.items()
            if m.loss_weight is not None} == {("task3", "hamiltonian"): 0.1}
    # the L-BFGS finishes of the full plans; quick plans and --lbfgs-steps 0 have none
    assert {(t, k): m.lbfgs for t in TASKS for k, m in full[t].models.items()
            if m.lbfgs} == {("task2", "lagrangian"): 1000, ("task3", "hamiltonian"): 200,
                               ("task4", "hamiltonian"): 1000, ("task4", "lagrangian"): 2000}
    assert make_plan(load_spec("task3"), ReproduceConfig("task3", quick=True)).models[
        "hamiltonian"].lbfgs == 0
    assert make_plan(load_spec("task3"), ReproduceConfig("task3", lbfgs_steps=0)).models[
        "hamiltonian"].lbfgs == 0
    assert full["task4"].models["lagrangian"].damping == (5, 3)
    assert full["task2"].models["lagrangian"].mass == (32, 4)
    assert full["task4"].physics_samples == 8000
    assert full["task1"].other_dt == 0.1 and full["task2"].other_dt == 0.15
    quick = make_plan(load_spec("task2"), ReproduceConfig("task2", quick=True, epochs=7))
    assert quick.models["lagrangian"].epochs == 7 and quick.data["duration"] < 10
    # early stopping where the recipe asks for it (task5's overfitting fixed-step runs), in
    # full runs only; the stage hands it to the training (test_recipe: a TrainConfig name)
    assert {(t, k): m.patience for t in TASKS for k, m in full[t].models.items()
            if m.patience is not None} == {("task5", "lagrangian"): 30, ("task5", "blackbox"): 10}
    assert make_plan(load_spec("task5"), ReproduceConfig(
        "task5", quick=True)).models["blackbox"].patience is None
    assert variant_model(t5, t5.variants[0], "blackbox").patience == 10
    assert {(t, k): m.overfit for t in TASKS for k, m in full[t].models.items()
            if m.overfit is not None} == {("task5", "lagrangian"): 2.0, ("task5", "blackbox"): 2.0}
    # the test loss on a subset of task5's large held-out sets, in full runs only
    assert {(t, k): m.test_samples for t in TASKS for k, m in full[t].models.items()
            if m.test_samples is not None} == {("task5", "lagrangian"): 45000,
                                        ("task5", "blackbox"): 45000}
    assert make_plan(load_spec("task5"), ReproduceConfig(
        "task5", quick=True)).models["lagrangian"].test_samples is None


def _err(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: "), err
    return err[0]


def test_reproduce_unknown_task_is_one_line_error(tmp_path, capsys):
    assert main(["reproduce", "task9", "--quick", "--out", str(tmp_path / "x")]) == 2
    assert "task9" in _err(capsys)
    assert main(["reproduce", "task1", "--seeds", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--seeds" in _err(capsys)
    assert main(["reproduce", "task1", "--jobs", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--jobs must be an integer >= 1, got 0" in _err(capsys)
    assert main(["reproduce", "challenges", "--jobs", "2", "--out", str(tmp_path / "x")]) == 2
    assert "--jobs: challenges runs its models one at a time" in _err(capsys)
    assert not (tmp_path / "x").exists()


def test_jobs_progress_shows_the_models_and_keeps_log_lines(capsys):
    """reproduce --jobs: one bar over the models, where each running one is, and the workers'
    log lines printed whole above it."""
    from softpinn.bridge.cli.bars import EpochBar
    from softpinn.progress import Progress, TrainProgress

    def model_done(key, done):
        return Progress(done=done, total=2, unit="model", label=key, phase="done")

    bar = EpochBar()
    bar(Progress(done=0, total=2, unit="model", phase="start"))
    bar(TrainProgress(done=3, total=10, unit="epoch", label="0", phase="adamw", epoch=3,
                      epochs=10, train_loss=(1.0,), model="50Hz/lagrangian"))
    bar.write("[train/100Hz/blackbox] ...")
    bar(model_done("100Hz/blackbox", 1))
    shown = bar.models.bar.format_dict
    assert (shown["n"], shown["total"]) == (1, 2)
    assert "50Hz/lagrangian 3/10 epochs" in shown["postfix"]
    bar(model_done("50Hz/lagrangian", 2))
    bar.write("50Hz/lagrangian: test 1e-3")
    bar.close()
    err = capsys.readouterr().err
    assert "[train/100Hz/blackbox] ...\n" in err and "50Hz/lagrangian: test 1e-3\n" in err


def test_a_serial_full_run_says_what_jobs_would_do(monkeypatch):
    import os

    from softpinn.bridge.tasks.parallel import suggest_jobs

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    lines = []
    suggest_jobs(6, lines.append)
    suggest_jobs(1, lines.append)  # one model: nothing to run side by side
    assert lines == ["[models] 6 models, one at a time: --jobs 4 would train 4 side by side on "
                     "this machine's 4 cores"]
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    suggest_jobs(6, lines.append)  # one core: nothing to spare
    assert len(lines) == 1


def test_analyze_cli_and_its_errors(quick_runs, tmp_path, capsys):
    result = quick_runs("task1")
    run = result.out_dir / "train" / "main" / "lagrangian" / "run"
    out = tmp_path / "an"
    assert main(["analyze", str(run), "task1", "--q", "0.5", "0.5", "0", "0", "0", "-0.8",
                 "--transform", "alpha", "pointwise", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert np.asarray(payload["q"]).shape == (3, 2)
    assert set(payload["transforms"]) == {"alpha", "pointwise"}
    assert (out / "report.md").is_file()
    # the forces along the run's own training trajectories, learned ones divided by alpha
    forces, accel = payload["forces"], payload["accelerations"]
    assert forces["samples"] > 0 and forces["meta"]["scale_from"] == "alpha"
    # and the accelerations, M^-1 times each term, with no transform
    assert accel["frame"] == "acceleration" and accel["scale"] == 1
    assert accel["samples"] == forces["samples"] and math.isfinite(accel["error"]["net"])
    text = (out / "report.md").read_text()
    assert "## Forces along the data" in text and "## Accelerations along the data" in text
    assert (out / "accelerations.png").is_file()
    assert main(["analyze", str(run), "task1", "--samples", "0", "--transform", "alpha",
                 "--out", str(tmp_path / "f"), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["forces"] is None and payload["accelerations"] is None
    # without --json, analyze ends with its headline: each transform's status and residuals
    assert main(["analyze", str(run), "task1", "--samples", "0", "--transform", "alpha",
                 "pointwise", "--out", str(tmp_path / "h")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("alpha: ") and "alpha = " in lines[0] and " %" in lines[0]
    assert lines[1].startswith("pointwise: ") and lines[-1].startswith("wrote ")
    assert main(["analyze", str(run), "task1", "--samples", "-1", "--out",
                 str(tmp_path / "g")]) == 2
    assert "--samples" in _err(capsys)
    assert main(["analyze", str(run), "task1", "--points", "0", "--out",
                 str(tmp_path / "g")]) == 2
    assert "--points: expected a count >= 1, got 0" in _err(capsys)
    assert main(["analyze", str(run), "task1", "--data", str(tmp_path / "none.npz"), "--out",
                 str(tmp_path / "h")]) == 2
    assert "none.npz" in _err(capsys)
    # without alpha a Lagrangian model's forces are not compared; its accelerations are
    assert main(["analyze", str(run), "task1", "--transform", "pointwise", "--samples", "50",
                 "--out", str(tmp_path / "i"), "--json"]) == 0
    captured = capsys.readouterr()
    payload = json.loads(captured.out)
    assert payload["forces"] is None and payload["accelerations"]["samples"] == 50
    assert "comparing the accelerations only" in captured.err
    # a run of another model size
    assert main(["analyze", str(run), "task4", "--out", str(tmp_path / "b")]) == 2
    assert "n=2" in _err(capsys)
    # an unknown transform
    assert main(["analyze", str(run), "task1", "--transform", "magic", "--out",
                 str(tmp_path / "c")]) == 2
    assert "magic" in _err(capsys)
    # a q of the wrong length
    assert main(["analyze", str(run), "task1", "--q", "0.1", "0.2", "0.3", "--out",
                 str(tmp_path / "d")]) == 2
    assert "multiple of n = 2" in _err(capsys)
    # a black-box run has no matrices
    bb = result.out_dir / "train" / "main" / "blackbox" / "run"
    assert main(["analyze", str(bb), "task1", "--out", str(tmp_path / "e")]) == 2
    assert "black-box" in _err(capsys)


# ------------------------------------------------------------------ the notebooks

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("task*.ipynb"))
CONTROL = Path(__file__).parent.parent / "notebooks" / "control.ipynb"


def test_one_notebook_per_task():
    assert [p.stem for p in NOTEBOOKS] == ["task1", "task2", "task3", "task4", "task5"]
    assert set(HERE) | {"task4", "task5"} == set(TASKS)


@pytest.mark.parametrize("path", [*(p for p in NOTEBOOKS if p.stem in HERE), CONTROL],
                         ids=lambda p: p.stem)
def test_notebook_executes(path, quick_runs, monkeypatch):
    run_notebook(path, quick_runs, monkeypatch)


def run_notebook(path, quick_runs, monkeypatch):
    """Execute a notebook on the session's quick runs: no errors, at least three figures."""
    # the notebook then finds every stage done and only reports (control: task3's runs)
    quick_runs("task3" if path == CONTROL else path.stem)
    monkeypatch.setenv("SOFTPINN_OUT", str(quick_runs.root))
    monkeypatch.setenv("SOFTPINN_QUICK", "1")
    monkeypatch.setenv("SOFTPINN_EPOCHS", str(QUICK_EPOCHS))
    monkeypatch.setenv("SOFTPINN_LBFGS", "0")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 3


def _interrupted_model():
    from softpinn.bridge.tasks.parallel import WorkerInterrupted

    raise WorkerInterrupted("main/lagrangian: interrupted")


def _failing_model():
    from softpinn.errors import UserError

    raise UserError("task.toml: field 'x': expected a number")


def _logged_model(path: str, name: str, delay: float) -> list[str]:
    import time

    time.sleep(delay)
    with open(path, "a") as f:
        f.write(name + "\n")
    return [name]


def test_jobs_after_work_waits_for_its_models(tmp_path):
    """Work ``after`` the models (a data set's figures) starts once the models it needs are
    done (one not in the run counts as done), on the next free worker: here a free worker
    waits for the slow model instead of taking it at once."""
    from softpinn.bridge.tasks.parallel import run_models

    order = tmp_path / "order.txt"
    ran = run_models([("a", _logged_model, (str(order), "a", 1.0), 1)], jobs=2,
                     log=lambda _: None, progress=None,
                     after=[("draw", ["a", "gone"], _logged_model, (str(order), "draw", 0.0)),
                            ("free", ["gone"], _logged_model, (str(order), "free", 0.0))])
    assert order.read_text().split() == ["free", "a", "draw"] and ran == {"a", "draw", "free"}


def test_jobs_workers_errors_and_interruptions_reach_the_caller():
    """A worker's user error is the caller's (one line at the command line), and a worker
    interrupted first (Ctrl-C reaches every process) stops the run as Ctrl-C does."""
    from softpinn.bridge.tasks.parallel import run_models
    from softpinn.errors import UserError

    lines = []
    with pytest.raises(UserError, match="field 'x': expected a number"):
        run_models([("a", _failing_model, (), 1), ("b", _failing_model, (), 1)], jobs=2,
                   log=lines.append, progress=None)
    with pytest.raises(KeyboardInterrupt):
        run_models([("c", _interrupted_model, (), 1)], jobs=2, log=lines.append, progress=None)
    assert lines[-1].startswith("interrupted: the models in training save a checkpoint")
