"""``softpinn reproduce cosserat`` (bridge/cosserat, issue 43 item 4): the quick form end to end
through the CLI (record the Cosserat-rod stand-in, import, train three networks, predict, the
baselines, the report), the report's table and verdicts, the stages reused by a second call, and
the one line a missing optional extra gives."""

from __future__ import annotations

import json
import math
import re

import pytest

from softpinn.bridge.cli import main
from softpinn.bridge.cosserat import pipeline
from softpinn.bridge.report.cosserat import ROWS

NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?"
CELL = re.compile(rf"^(?P<mean>{NUMBER}) ± (?P<std>{NUMBER})(?: \((?P<mark>[^)]*)\))?$")


def test_a_missing_pyelastica_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(pipeline, "has_pyelastica", lambda: False)
    code = main(["reproduce", "cosserat", "--quick", "--quiet", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err == ["softpinn: error: softpinn reproduce cosserat needs the optional extra: "
                   "pip install 'softpinn[cosserat]'"]
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_flags_the_study_sets_itself_are_refused(tmp_path, capsys):
    assert main(["reproduce", "cosserat", "--epochs", "3", "--out", str(tmp_path / "o")]) == 2
    assert "the cosserat study sets its own budgets" in capsys.readouterr().err


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    pytest.importorskip("elastica")  # the optional extra "cosserat" (the test extra has it)
    out = tmp_path_factory.mktemp("cosserat") / "quick"
    assert main(["reproduce", "cosserat", "--quick", "--quiet", "--out", str(out)]) == 0
    return out


def _table(report: str) -> tuple[list[str], dict[str, list[str]]]:
    lines = [ln for ln in report.splitlines() if ln.startswith("| ")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for ln in lines[1:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return head, rows


@pytest.mark.slow
def test_quick_run_writes_the_table_and_the_verdicts(quick_run):
    report = (quick_run / "report.md").read_text()
    head, rows = _table(report)
    results = json.loads((quick_run / "results.json").read_text())
    long = results["plan"]["horizons"][-1]  # clipped to the quick recordings' 3 s
    assert head == ["model", "clean 1 s", f"clean {long:g} s", "noisy 1 s", f"noisy {long:g} s"]
    assert list(rows) == [label for label, _, _ in ROWS]
    for label, cells in rows.items():
        assert len(cells) == 4
        for cell in cells:
            if cell.startswith(("diverged", "no model")):
                continue  # marked, never a silent number
            m = CELL.match(cell)
            assert m, f"{label}: {cell!r} is neither a number nor marked"
            assert math.isfinite(float(m["mean"])) and math.isfinite(float(m["std"]))
            assert m["mark"] is None or "left the training range" in m["mark"]
    verdicts = [ln for ln in report.splitlines() if ln.startswith(("- clean: ", "- noisy: "))]
    for variant in ("clean", "noisy"):
        for label in ("black box", "Lagrangian", "Hamiltonian-from-velocity"):
            line = next(v for v in verdicts if v.startswith(f"- {variant}: {label}: "))
            assert " at 1 s " in line and (" beats " in line or " LOSES " in line)
    assert "seed 0" in report and "plan.json" in report
    assert report.count("actuator (every network and baseline): ") == 2
    assert len(re.findall(r"  - baselines: lagged ARX order \d+, (least squares|rollout fit)",
                          report)) == 2  # what its fit chose, per variant


@pytest.mark.slow
def test_quick_run_results_are_strict_json_and_marked(quick_run):
    text = (quick_run / "results.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    results = json.loads(text)
    assert results["task"] == "cosserat" and results["quick"] is True
    for variant in ("clean", "noisy"):
        v = results["results"][variant]
        assert len(v["record"]["files"]) == results["plan"]["trajectories"]
        assert v["import"]["test"] == [2] and v["import"]["validation"] == [1]
        for kind in ("blackbox", "lagrangian", "hamiltonian"):
            assert v["networks"][kind]["train"]["config"]["model"]["n"] == 2  # bending only
            # every network gets the variant's one actuator (identified once, given as numbers)
            assert v["networks"][kind]["train"]["config"]["actuator"] == v["actuator"]["text"]
            for h in v["networks"][kind]["predict"]["horizons"].values():
                assert (h["mean"] is None) == (h["diverged"] > 0)
    hamiltonian = results["results"]["clean"]["networks"]["hamiltonian"]["train"]["config"]
    assert hamiltonian["momenta"] == "velocity"


@pytest.mark.slow
def test_a_second_call_reuses_every_stage(quick_run, capsys):
    before = (quick_run / "clean" / "train" / "lagrangian" / "done.json").stat().st_mtime_ns
    assert main(["reproduce", "cosserat", "--quick", "--quiet", "--out", str(quick_run)]) == 0
    after = (quick_run / "clean" / "train" / "lagrangian" / "done.json").stat().st_mtime_ns
    assert before == after
    assert "wrote" in capsys.readouterr().out
