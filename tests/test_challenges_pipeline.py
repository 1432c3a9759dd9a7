"""``reproduce challenges``' orchestration: studies run into their folders, finished ones are
reused, the report gathers the targets and each study's section, bad flags are refused."""

from __future__ import annotations

import json
import sys
import types

import pytest

from softpinn.bridge.app import reproduce, runner, study_for
from softpinn.bridge.challenges import pipeline
from softpinn.bridge.cli import main
from softpinn.bridge.tasks import ReproduceConfig
from softpinn.errors import UserError

CALLS: list[str] = []


def _fake_study(name):
    def run_study(out, *, quick, log, progress=None):
        CALLS.append(name)
        (out / "figure.png").write_bytes(b"png")
        return {"title": name, "markdown": f"# {name} results\n\n![f]({name}/figure.png)",
                "results": {"quick": quick, "targets": [
                    {"what": f"{name} speed", "target": "≥ 2×", "measured": "3.1×",
                     "met": name != "labels"}]},
                "seconds": 1.5}
    return run_study


@pytest.fixture
def fake_studies(monkeypatch):
    CALLS.clear()
    for name, _ in pipeline.STUDIES:
        mod = types.ModuleType(f"softpinn.bridge.challenges.{name}")
        mod.run_study = _fake_study(name)
        monkeypatch.setitem(sys.modules, mod.__name__, mod)


def test_studies_run_once_and_the_report_gathers_them(fake_studies, tmp_path, monkeypatch):
    monkeypatch.setattr(runner, "machine_description", lambda: "test box")
    result = reproduce(ReproduceConfig("challenges", quick=True), tmp_path / "ch")
    out, report = result.out_dir, result.report
    assert CALLS == [n for n, _ in pipeline.STUDIES]
    assert result.plan is None and result.results["studies"]["fast"]["seconds"] == 1.5
    text = report.read_text()
    assert "**This is a quick run**" in text and "test box" in text
    # the targets table, met and missed as the studies said
    assert "| 2b | labels speed | ≥ 2× | 3.1× | missed |" in text
    assert "| 1 | fast speed | ≥ 2× | 3.1× | met |" in text
    # each study's section under the report's own heading, its headings one level down
    for name, title in pipeline.STUDIES:
        assert f"## {title}" in text and f"\n## {name} results" in text
    saved = json.loads((out / "results.json").read_text())
    assert saved == json.loads(json.dumps(result.results))
    assert list(saved) == ["task", "quick", "seconds", "machine", "studies"]
    assert saved["machine"] == "test box" and saved["studies"]["fast"]["seconds"] == 1.5
    assert "markdown" not in saved["studies"]["fast"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert "fast/figure.png" in json.dumps(manifest)
    # a second call reuses every finished study; another setting (full) runs them again
    reproduce(ReproduceConfig("challenges", quick=True), out)
    assert len(CALLS) == len(pipeline.STUDIES)
    reproduce(ReproduceConfig("challenges"), out)
    assert len(CALLS) == 2 * len(pipeline.STUDIES)
    assert "quick run" not in report.read_text()


def test_the_registry_picks_each_tasks_study():
    """``reproduce`` dispatches through the registry: the challenges and the experiment have
    studies of their own, every paper task and a spec file of one's own the task pipeline."""
    from softpinn.bridge.app.studies import ChallengesStudy, ExperimentStudy, TaskStudy

    assert isinstance(study_for("challenges"), ChallengesStudy)
    assert isinstance(study_for("experiment"), ExperimentStudy)
    assert all(isinstance(study_for(t), TaskStudy) for t in ("task1", "task5", "my-arm.toml"))


def test_a_users_folder_is_not_written_into(fake_studies, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert main(["reproduce", "challenges", "--quick", "--quiet", "--out", str(mine)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("softpinn: error: --out:") and "\n" not in err and CALLS == []
    assert (mine / "notes.txt").read_text() == "keep"


@pytest.mark.parametrize("kw, flag", [({"seeds": 3}, "--seeds"), ({"epochs": 5}, "--epochs"),
                                      ({"float32": True}, "--float32")])
def test_task_flags_are_refused(kw, flag):
    with pytest.raises(UserError, match=f"{flag}: the challenges' studies set their own"):
        ReproduceConfig(task="challenges", quick=True, **kw)


@pytest.mark.parametrize("eq10_reaches", [True, False])
def test_fast_recipe_goes_on_with_the_pair_loss_only_where_eq10_falls_short(
        tmp_path, monkeypatch, eq10_reaches):
    """Challenge 1's fast recipe: eq. 10 scored by the pair loss, stopped at the level; the
    pair loss from eq. 10's best model only where eq. 10 did not get there, its time counted
    after eq. 10's whole run."""
    from softpinn.bridge.challenges import fast

    level = fast.paper_level()
    calls = []

    def h(*rows):
        return [{"epoch": e, "test_loss": t, "seconds": s, "phase": p} for e, t, s, p in rows]

    def fake_train(spec, plan, files, folder, progress, *, loss, budget, target=None,
                   init=None):
        calls.append({"loss": loss, "target": target, "init": init, "folder": folder.name})
        if loss == "pair" and init is None:  # today: reaches the level in L-BFGS at 300 s
            hist = h((0, 1.0, 0.0, "adamw"), (10, 0.5 * level, 300.0, "lbfgs"))
        elif loss == "accel":
            end = 0.9 * level if eq10_reaches else 3.0 * level
            hist = h((0, 1.0, 0.0, "adamw"), (300, 10 * level, 20.0, "adamw"),
                     (310, end, 50.0, "lbfgs"))
        else:  # the pair loss from eq. 10's model
            hist = h((0, 3.0 * level, 0.0, "adamw"), (5, 0.8 * level, 40.0, "lbfgs"))
        return {"run": str(folder / "run"), "wall_s": hist[-1]["seconds"] + 1,
                "train_s": hist[-1]["seconds"],
                "best_test_loss": min(r["test_loss"] for r in hist), "stopped": "x",
                "history": hist, "config": {}, "load_after": "0"}

    monkeypatch.setattr(fast, "_train", fake_train)
    monkeypatch.setattr(fast, "stage_data", lambda spec, plan, folder: {"variants": {
        "main": {"physics": {"path": "x.npz", "train": [0], "test": [1]}}}})
    ttl = fast._time_to_loss(tmp_path, False, lambda s: None, None)
    assert ttl["level"] == level and ttl["level_is_paper"] and ttl["today_s"] == 300.0
    warm = next(c for c in calls if c["loss"] == "accel")
    assert warm["target"] == level and warm["init"] is None
    pair_after = [c for c in calls if c["init"] is not None]
    if eq10_reaches:
        assert ttl["reached_in"] == "warm" and ttl["fast_s"] == 50.0 and not pair_after
        assert "fast" not in ttl["runs"] and ttl["curves"]["fast"] == []
    else:
        (after,) = pair_after
        assert after["loss"] == "pair" and after["target"] == level
        assert after["init"] == str(tmp_path / "train-warm" / "run")
        assert ttl["reached_in"] == "fast" and ttl["fast_s"] == 50.0 + 40.0
        assert [c[0] for c in ttl["curves"]["fast"]] == [50.0, 90.0]
    assert ttl["speedup"] == pytest.approx(300.0 / ttl["fast_s"])
    fast._figure({"batch": 8, "n": {"6": {"kinds": {"lagrangian": {"step_ms": 1.0}}}}}, ttl,
                 tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 0
