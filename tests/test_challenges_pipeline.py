"""``reproduce challenges``' orchestration: studies run into their folders, finished ones are
reused, the report gathers the targets and each study's section, bad flags are refused."""

from __future__ import annotations

import json
import sys
import types

import pytest

from softpinn.bridge.challenges import pipeline
from softpinn.bridge.cli import main
from softpinn.bridge.errors import UserError
from softpinn.bridge.tasks import ReproduceConfig

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


def test_studies_run_once_and_the_report_gathers_them(fake_studies, tmp_path):
    out, report, results, _ = pipeline.run_challenges(tmp_path / "ch", quick=True,
                                                      machine="test box")
    assert CALLS == [n for n, _ in pipeline.STUDIES]
    text = report.read_text()
    assert "**This is a quick run**" in text and "test box" in text
    # the targets table, met and missed as the studies said
    assert "| 2b | labels speed | ≥ 2× | 3.1× | missed |" in text
    assert "| 1 | fast speed | ≥ 2× | 3.1× | met |" in text
    # each study's section under the report's own heading, its headings one level down
    for name, title in pipeline.STUDIES:
        assert f"## {title}" in text and f"\n## {name} results" in text
    assert json.loads((out / "results.json").read_text())["studies"]["fast"]["seconds"] == 1.5
    manifest = json.loads((out / "manifest.json").read_text())
    assert "fast/figure.png" in json.dumps(manifest)
    # a second call reuses every finished study; another setting (full) runs them again
    pipeline.run_challenges(out, quick=True)
    assert len(CALLS) == len(pipeline.STUDIES)
    pipeline.run_challenges(out, quick=False)
    assert len(CALLS) == 2 * len(pipeline.STUDIES)
    assert "quick run" not in report.read_text()


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
