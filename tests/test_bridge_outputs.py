"""Nothing of the user's overwritten by ``analyze`` and ``reproduce`` (issue 15): an --out that
holds files softpinn did not write is refused unless --force, which removes nothing; a rerun into
the command's own folder works, also after an interruption; and ``analyze`` refuses a true model
that is not the run's, and arguments given in the wrong order, with one line."""

from __future__ import annotations

import json

import pytest

from softpinn.bridge.base import outputs
from softpinn.bridge.cli import main
from softpinn.errors import UserError


def _err(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("softpinn: error: "), err
    return err[0]


def test_claim_new_empty_own_and_foreign_folders(tmp_path):
    out = outputs.claim(tmp_path / "new", "analyze")
    assert json.loads((out / "manifest.json").read_text())["command"] == "analyze"
    (out / "report.md").write_text("ours")
    outputs.record(out, [out / "report.md"])
    # a rerun (also one after an interruption: the claim is written first) is the owner's
    assert outputs.claim(out, "analyze") == out
    assert "report.md" in json.loads((out / "manifest.json").read_text())["files"]
    with pytest.raises(UserError, match="output of softpinn analyze"):
        outputs.claim(out, "reproduce")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.md").write_text("my notes")
    with pytest.raises(UserError, match="files softpinn did not write; choose another folder"):
        outputs.claim(mine, "analyze")
    outputs.claim(mine, "analyze", force=True)
    assert (mine / "report.md").read_text() == "my notes"  # --force removes nothing
    empty = tmp_path / "empty"
    empty.mkdir()
    outputs.claim(empty, "reproduce")
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="is a file, not a folder"):
        outputs.claim(tmp_path / "file", "analyze")
    with pytest.raises(UserError, match="is a file, not a folder"):
        outputs.claim(tmp_path / "file" / "sub", "analyze")


def test_a_rerun_keeps_the_files_their_user_edited(tmp_path):
    """A file a finished command recorded and its user edited since is not written over by a
    rerun without --force; after an interrupted run (claimed, never recorded) the files it
    rewrote are its own, and the rerun goes on."""
    out = outputs.claim(tmp_path / "a", "analyze")
    (out / "summary.md").write_text("ours")
    (out / "gone.md").write_text("ours too")
    outputs.record(out, [out / "summary.md", out / "gone.md"])
    (out / "gone.md").unlink()  # a recorded file deleted: nothing of anybody's to keep
    assert outputs.claim(out, "analyze") == out
    outputs.record(out, [out / "summary.md"])
    (out / "summary.md").write_text("ours, with my notes")
    with pytest.raises(UserError, match=r"summary.md changed after softpinn analyze wrote it; "
                                        r"move it away, or --force"):
        outputs.claim(out, "analyze")
    with pytest.raises(UserError, match="summary.md changed"):
        outputs.check(out, "analyze")
    assert (out / "summary.md").read_text() == "ours, with my notes"
    outputs.claim(out, "analyze", force=True)
    # interrupted: claimed, a file rewritten, never recorded: the next run is not refused
    (out / "summary.md").write_text("half of a new summary")
    assert outputs.changed_files(out) == []
    assert outputs.claim(out, "analyze") == out


def test_reproduce_refuses_a_users_folder_before_any_work(tmp_path, capsys):
    mine = tmp_path / "paper"
    mine.mkdir()
    (mine / "report.md").write_text("my draft")
    assert main(["reproduce", "task1", "--quick", "--out", str(mine)]) == 2
    assert "--out: " in (line := _err(capsys)) and "did not write" in line and "--force" in line
    assert (mine / "report.md").read_text() == "my draft"
    assert sorted(p.name for p in mine.iterdir()) == ["report.md"]


@pytest.fixture(scope="module")
def task1_run(tmp_path_factory):
    """A tiny Lagrangian network trained on task 1's own data (seconds: the session's shared
    quick runs live on another xdist worker, where reusing them would mean running one again)."""
    root = tmp_path_factory.mktemp("task1-run")
    data, run = root / "task1.npz", root / "run"
    assert main(["simulate", "task1", "--out", str(data), "--trajectories", "3",
                 "--duration", "1", "--quiet"]) == 0
    assert main(["train", str(data), "--model", "lagrangian", "--out", str(run), "--epochs", "2",
                 "--width", "8", "--test-trajectories", "2", "--quiet"]) == 0
    return run


def test_analyze_protects_the_users_files(task1_run, tmp_path, capsys):
    args = ["analyze", str(task1_run), "task1", "--samples", "0", "--transform", "alpha",
            "--points", "12"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.md").write_text("my draft")
    assert main([*args, "--out", str(mine)]) == 2
    assert "did not write" in _err(capsys)
    assert (mine / "report.md").read_text() == "my draft"
    # into the run directory itself: refused, nothing of the run touched
    before = {p.name: p.read_bytes() for p in task1_run.iterdir() if p.is_file()}
    assert main([*args, "--out", str(task1_run)]) == 2
    assert "run directory of softpinn train" in _err(capsys)
    assert {p.name: p.read_bytes() for p in task1_run.iterdir() if p.is_file()} == before
    # its own folder again: fine; the manifest lists what it wrote
    out = tmp_path / "an"
    assert main([*args, "--out", str(out)]) == 0
    assert main([*args, "--out", str(out)]) == 0
    capsys.readouterr()
    files = json.loads((out / "manifest.json").read_text())["files"]
    assert "report.md" in files and "analysis.json" in files
    # a file of it the user edited is kept: refused in one line until --force
    (out / "report.md").write_text("my edit")
    assert main([*args, "--out", str(out)]) == 2
    assert "report.md changed after softpinn analyze wrote it" in _err(capsys)
    assert (out / "report.md").read_text() == "my edit"
    assert main([*args, "--out", str(out), "--force"]) == 0
    capsys.readouterr()
    # --force writes beside the user's other files and removes none
    (mine / "notes.txt").write_text("keep me")
    assert main([*args, "--out", str(mine), "--force"]) == 0
    assert (mine / "notes.txt").read_text() == "keep me"
    (tmp_path / "f").write_text("x")
    assert main([*args, "--out", str(tmp_path / "f" / "sub")]) == 2
    assert "is a file, not a folder" in _err(capsys)


def test_analyze_refuses_another_models_physics_and_swapped_arguments(task1_run, tmp_path,
                                                                     capsys):
    args = ["--samples", "0", "--transform", "alpha", "--points", "12"]
    # task2 has task1's sizes but other physics: refused unless on purpose
    assert main(["analyze", str(task1_run), "task2", *args, "--out", str(tmp_path / "a")]) == 2
    line = _err(capsys)
    assert line.startswith("softpinn: error: model: ") and "--model-mismatch-ok" in line
    assert not (tmp_path / "a").exists()
    assert main(["analyze", str(task1_run), "task2", *args, "--model-mismatch-ok",
                 "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    data = json.loads((task1_run / "config.json").read_text())["dataset"]["path"]
    assert main(["analyze", str(task1_run), data, *args, "--out", str(tmp_path / "b")]) == 2
    assert "is a data set, not a model" in _err(capsys)
    assert main(["analyze", "task1", str(task1_run), *args, "--out", str(tmp_path / "c")]) == 2
    assert "the order is `softpinn analyze RUN MODEL`" in _err(capsys)
    assert main(["analyze", data, "task1", *args, "--out", str(tmp_path / "d")]) == 2
    assert "RUN is the folder" in _err(capsys)


def test_analyze_says_true_is_nominal_for_recorded_data(tmp_path):
    """A run that learned from `softpinn import`'s recordings: the analysis' "true" matrices
    are the spec's nominal model, and it says so; simulated data need no note."""
    from types import SimpleNamespace

    import numpy as np

    from softpinn.bridge.cli._analyze_run import _recorded_notes

    spec = SimpleNamespace(name="myarm")
    for source, expect in (("import", 1), (None, 0)):
        path = tmp_path / f"{source}.npz"
        np.savez(path, meta=np.array(json.dumps({"source": source})))
        notes = _recorded_notes(SimpleNamespace(info={"dataset": {"path": str(path)}}), spec)
        assert len(notes) == expect
    assert "'true' is the nominal model myarm, not a measurement" in _recorded_notes(
        SimpleNamespace(info={"dataset": {"path": str(tmp_path / "import.npz")}}), spec)[0]
    assert _recorded_notes(SimpleNamespace(info={"dataset": {"path": None}}), spec) == []


def test_the_manifest_is_written_whole_as_before(tmp_path, monkeypatch):
    """The manifest goes through the one strict writer (``softpinn.files``): the same bytes as
    before (indent 2, a newline at the end), no temporary file left, and a folder that cannot
    be written is one line."""
    out = outputs.claim(tmp_path / "o", "analyze")
    text = (out / "manifest.json").read_text()
    assert text == json.dumps({"format": "softpinn-manifest", "command": "analyze", "files": {},
                               "complete": False}, indent=2) + "\n"
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json"]

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs, "write_json", lambda path, obj: full())
    with pytest.raises(UserError, match=r"manifest\.json: cannot write there \(No space left"):
        outputs.record(out, [])
