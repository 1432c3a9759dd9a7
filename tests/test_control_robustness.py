"""`softpinn control` when things go wrong (issue 46): one Ctrl-C stops it within seconds with
exit status 130 (CasADi used to turn it into a failed plant step), a controller that raises
leaves the others' results and names itself, failed solves carry their cause, and a line is
said before each controller is built."""

from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from softpinn.bridge import cli
from softpinn.bridge.control import ControlConfig, MPCConfig, compare
from softpinn.bridge.control.failures import cause, count_causes, fallback
from softpinn.bridge.control.interrupt import Interrupts
from softpinn.bridge.control.loop import metrics
from softpinn.errors import UserError

#: the module of compare() (its name is the function's in the package)
compare_module = importlib.import_module("softpinn.bridge.control.compare")



#: compiled libraries go to a cache of this test session (conftest.py)
pytestmark = pytest.mark.usefixtures("session_cache")


def _config(**kw):
    mpc = MPCConfig(horizon=5, dt=0.05, u_min=(-5.0,), u_max=(5.0,), codegen=False)
    return ControlConfig(mpc=mpc, duration=0.2, references=("step",), **kw)


def test_ctrl_c_stops_control_within_seconds(tmp_path):
    """One SIGINT while the loop steps: exit 130 within seconds, what finished kept (no
    figures)."""
    out = tmp_path / "c"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with subprocess.Popen(
        [sys.executable, "-c", "import sys; from softpinn.bridge.cli import main; "
         "sys.exit(main())", "control", "task4", "--out", str(out),
         "--no-codegen", "--reference", "circle", "--duration", "600",
         # IPOPT, whose iterations CasADi checks for Ctrl-C: the old code took it for a failed
         # solve and went on
         "--solver", "ipopt", "--max-iter", "5", "--horizon", "10"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
        # SIGINT as in a terminal, even where pytest (xdist's workers) or a shell ignores it
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) as proc:
        err = []

        def read():
            while chunk := proc.stderr.read1(4096):
                err.append(chunk.decode(errors="replace"))

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            deadline = time.monotonic() + 300
            while "step/s" not in "".join(err) and "s/step" not in "".join(err):
                assert proc.poll() is None, "".join(err)
                assert time.monotonic() < deadline, "control never started stepping"
                time.sleep(0.1)
            time.sleep(1.0)  # well inside the loop: the plant's cvodes and the solves
            t0 = time.monotonic()
            proc.send_signal(signal.SIGINT)
            rc = proc.wait(timeout=60)
            waited = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        reader.join(timeout=5)
    text = "".join(err)
    assert rc == 130, text[-2000:]
    assert waited < 15, f"{waited:.1f} s after Ctrl-C"
    assert "softpinn: interrupted" in text
    result = json.loads((out / "results.json").read_text())
    assert result["interrupted"] is True and not (out / "figures").exists()
    assert "Interrupted" in (out / "report.md").read_text()


def test_interrupts_defer_sigint_to_the_check(ctrl_c_raises):
    """The first SIGINT is held for check(), a second raises at once; the handler goes back."""
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt), Interrupts() as guard:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        assert guard.pending  # not raised yet
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        guard.check()
    assert signal.getsignal(signal.SIGINT) is before
    # an error while an interrupt is pending (a compiler killed by it) is the interrupt
    with pytest.raises(KeyboardInterrupt), Interrupts() as guard:
        guard.pending = True
        raise UserError("compiler: gcc was killed")


def test_a_failed_controller_keeps_the_others(msd_full_spec, tmp_path, monkeypatch, capsys):
    """The true controller's build raises: the linearised one's results are written, the
    failure is named in results.json, report.md and one CLI line with exit status 2."""
    real = compare_module.MPC

    def build(pm, *args, **kw):
        if pm.name == "true":
            raise RuntimeError("boom: the solver could not be built\nsecond line")
        return real(pm, *args, **kw)

    monkeypatch.setattr(compare_module, "MPC", build)
    out = tmp_path / "c"
    lines = []
    result = compare(msd_full_spec, [], out, _config(), log=lines.append)
    assert list(result["results"]["step"]) == ["linearised"]
    assert result["failed"]["true"]["stage"] == "build"
    assert result["failed"]["true"]["error"] == "boom: the solver could not be built second line"
    saved = json.loads((out / "results.json").read_text())
    assert saved["failed"]["true"]["type"] == "RuntimeError"
    assert "Traceback" in saved["failed"]["true"]["traceback"]
    assert list(saved["results"]["step"]) == ["linearised"] and saved["interrupted"] is False
    report = (out / "report.md").read_text()
    assert "**true failed** building its MPC: boom" in report
    assert (out / "figures").is_dir() and (out / "traces" / "step.npz").is_file()
    assert any(line.startswith("control: true failed building its MPC: boom") for line in lines)

    # a loop that raises on a reference, through the CLI: exit 2, one line naming it
    def solve_raises(pm, *args, **kw):
        mpc = real(pm, *args, **kw)
        if pm.name == "true":
            def solve(*a, **k):
                raise UserError("solver: out of memory")
            mpc.solve = solve
        return mpc

    monkeypatch.setattr(compare_module, "MPC", solve_raises)
    status = cli.main(["control", msd_full_spec, "--out", str(tmp_path / "d"), "--reference",
                       "step", "--duration", "0.2", "--horizon", "5", "--rate", "20",
                       "--no-codegen", "--quiet"])
    captured = capsys.readouterr()
    assert status == 2, captured.err
    assert captured.err.count("\n") == 1 and captured.err.startswith(
        "softpinn: error: control: 1 controller(s) failed: true (step): solver: out of memory")
    assert "linearised" in captured.out and "true: FAILED on step" in captured.out
    saved = json.loads((tmp_path / "d" / "results.json").read_text())
    assert list(saved["results"]["step"]) == ["linearised"] and "true" in saved["controllers"]
    assert "traceback" not in saved["failed"]["true"]  # a UserError says it all

    # nothing finished: the failure is the run's, raised as it was, and a fresh --out is freed
    monkeypatch.setattr(compare_module, "MPC", build)
    with pytest.raises(RuntimeError, match="boom"):
        compare(msd_full_spec, [], tmp_path / "e", _config(include_linear=False))


def test_a_long_build_says_what_it_does(msd_full_spec, tmp_path, monkeypatch):
    """A build longer than ANNOUNCE_AFTER says so while it runs, and how long it took."""
    real = compare_module.MPC

    def slow(pm, *args, **kw):
        time.sleep(0.5)
        return real(pm, *args, **kw)

    monkeypatch.setattr(compare_module, "MPC", slow)
    monkeypatch.setattr(importlib.import_module("softpinn.bridge.control.stepping"),
                        "ANNOUNCE_AFTER", 0.1)
    lines = []
    compare(msd_full_spec, [], None, _config(include_linear=False), log=lines.append)
    assert lines[0].startswith("control: building true's MPC (n = 2, horizon 5, sqp")
    assert lines[1].startswith("control: true's MPC built in ")


def test_failed_solves_are_counted_by_cause(msd_full_spec, tmp_path, monkeypatch):
    """Each failed solve's cause from its status; counts per controller in results.json and
    the report, with what a failed solve applies."""
    assert cause("QP failed (0)", "SOLVER_RET_INFEASIBLE") == "infeasible"
    assert cause("Maximum_Iterations_Exceeded", "SOLVER_RET_LIMITED") == "iteration limit"
    assert cause("Maximum_Iterations_Exceeded") == "iteration limit"
    assert cause("line search failed") == "numerical"
    assert cause("non-finite prediction") == "numerical"
    assert cause("QP failed (0)", "SOLVER_RET_UNKNOWN") == "numerical"
    assert cause("something else") == "other"
    assert count_causes([True, False, False, False], [None, "numerical", "infeasible",
                                                      "numerical"]) == \
        {"infeasible": 1, "numerical": 2}
    assert "shifted" in fallback("sqp") and "IPOPT" in fallback("ipopt")
    # metrics of a loop without causes (older callers): its failures count as "other"
    m = metrics({"y": np.zeros((3, 1)), "r": np.zeros((3, 1)), "u": np.zeros((2, 1)),
                 "success": np.array([True, False]), "status": ["converged", "x"],
                 "seconds": np.zeros(2), "iterations": np.ones(2, int)})
    assert m["failure_causes"] == {"other": 1} and m["failure_statuses"] == {"x": 1}

    # a controller whose every other solve fails with a QP the solver called infeasible
    real = compare_module.MPC

    def flaky(pm, *args, **kw):
        mpc = real(pm, *args, **kw)
        inner, calls = mpc._solve_sqp, [0]

        def solve_sqp(x0, R, u_prev):
            u, info = inner(x0, R, u_prev)
            calls[0] += 1
            if calls[0] % 2 == 0:
                mpc._unified = "SOLVER_RET_INFEASIBLE"
                info.update(success=False, status="QP failed (2)",
                            unified="SOLVER_RET_INFEASIBLE")
            return u, info

        mpc._solve_sqp = solve_sqp
        return mpc

    monkeypatch.setattr(compare_module, "MPC", flaky)
    result = compare(msd_full_spec, [], tmp_path / "c", _config(include_linear=False))
    met = result["results"]["step"]["true"]
    assert met["failures"] == met["steps"] // 2 > 0
    assert met["failure_causes"] == {"infeasible": met["failures"]}
    assert met["failure_statuses"] == {"QP failed (2)": met["failures"]}
    report = (tmp_path / "c" / "report.md").read_text()
    assert f"true on step: {met['failures']} infeasible" in report
    assert "A failed SQP solve applies the first input of its last accepted plan" in report
    assert f"{met['failures']}/{met['steps']}, {met['failures']} infeasible" in report
