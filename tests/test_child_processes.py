"""No compiler outlives its command (issue 15): an interrupt (Ctrl-C), SIGTERM or SIGKILL while
the C compiler runs kills the compiler and its children, and leaves no temporary file or build
folder; what a killed run leaves in the compiled-code cache is removed by the next compile.

The compiler here is a shell script that records its pid, starts a child (``sleep``, standing
for cc1) and waits: before the fix a Ctrl-C left both running, writing ``.so.tmp`` files."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import casadi as ca
import pytest

from softpinn.symbolic import _outputs as outputs
from softpinn.symbolic.codegen import _codegen as codegen


@pytest.fixture(autouse=True)
def _ctrl_c(ctrl_c_raises):
    """Every test here sends Ctrl-C (conftest's ``ctrl_c_raises``)."""


def slow_compiler(tmp_path: Path) -> Path:
    """A fake compiler: writes its pid and its child's pid, then waits for the child (30 s)."""
    script = tmp_path / "slowcc"
    script.write_text(
        "#!/bin/sh\n"
        f"echo $$ > {tmp_path}/cc.pid\n"
        "sleep 30 &\n"
        f"echo $! > {tmp_path}/child.pid\n"
        "wait\n"
    )
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return script


def toy(tag: str) -> dict[str, ca.Function]:
    q = ca.SX.sym("q", 2)
    return {"M": ca.Function(f"{tag}_M", [q], [ca.SX.eye(2) * (2 + ca.sin(q[0]))], ["q"], ["M"])}


def wait_for(path: Path, seconds: float = 20.0) -> int:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if path.is_file() and path.read_text().strip():
            return int(path.read_text())
        time.sleep(0.02)
    raise AssertionError(f"{path} never appeared")


def gone(pid: int, seconds: float = 5.0) -> bool:
    """The process has exited (a zombie waiting for a reaper counts as exited)."""
    deadline = time.monotonic() + seconds
    while True:
        try:
            with open(f"/proc/{pid}/stat") as fh:
                state = fh.read().rsplit(")", 1)[1].split()[0]
        except FileNotFoundError:
            return True
        if state in ("Z", "X"):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def interrupt_when(path: Path) -> threading.Thread:
    """Send SIGINT to the main thread (as Ctrl-C does) once ``path`` exists."""
    main = threading.main_thread().ident

    def run():
        wait_for(path)
        signal.pthread_kill(main, signal.SIGINT)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses /proc")


def test_ctrl_c_kills_the_compiler_and_its_children(tmp_path):
    cc = slow_compiler(tmp_path)
    (tmp_path / "build").mkdir()
    source = codegen.write_c(toy("ctrlc"), tmp_path / "build", "lib")
    thread = interrupt_when(tmp_path / "child.pid")
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        codegen.compile_c(source, tmp_path / "build" / "lib.so", compiler=str(cc), timeout=60)
    thread.join()
    assert time.monotonic() - start < 15
    assert gone(int((tmp_path / "cc.pid").read_text()))
    assert gone(int((tmp_path / "child.pid").read_text()))
    assert sorted(p.name for p in (tmp_path / "build").iterdir()) == ["lib.c"]  # no .so.tmp


def test_ctrl_c_during_a_cached_compile_leaves_no_build_folder(tmp_path):
    cc = slow_compiler(tmp_path)
    cache = tmp_path / "cache"
    thread = interrupt_when(tmp_path / "child.pid")
    with pytest.raises(KeyboardInterrupt):
        codegen.compile_functions(toy("ctrlc2"), directory=cache, compiler=str(cc), timeout=60)
    thread.join()
    assert gone(int((tmp_path / "child.pid").read_text()))
    assert not list(cache.rglob(".build-*")) and not list(cache.rglob("*.so*"))


RUN_COMPILE = """
import sys
import casadi as ca
from softpinn.symbolic import compile_functions
q = ca.SX.sym("q", 2)
fns = {"M": ca.Function("killed_M", [q], [ca.SX.eye(2) * (3 + ca.cos(q[1]))], ["q"], ["M"])}
compile_functions(fns, directory=sys.argv[1], compiler=sys.argv[2], timeout=60)
"""


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_killed_command_takes_its_compiler_along_and_the_next_compile_cleans_up(tmp_path, sig):
    """SIGKILL leaves Python no chance to clean up: the supervisor (told by the kernel that its
    parent died) kills the compiler's group; the build folder the dead run left in the cache is
    removed by the next compile, which then succeeds."""
    cc = slow_compiler(tmp_path)
    cache = tmp_path / "cache"
    proc = subprocess.Popen([sys.executable, "-c", RUN_COMPILE, str(cache), str(cc)])
    try:
        child = wait_for(tmp_path / "child.pid", 60)
        compiler = int((tmp_path / "cc.pid").read_text())
        proc.send_signal(sig)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert gone(compiler) and gone(child), "the compiler outlived the killed command"
    left = list(cache.glob("*/.build-*"))
    assert left, "the killed run was expected to leave its build folder"
    # the next compile of anything removes the dead run's build folder
    res = codegen.compile_functions(toy("after"), directory=cache)
    assert res.compiled and not list(cache.glob("*/.build-*"))
    assert not any(p.exists() for p in left)


def test_stale_build_folders_are_told_from_live_ones(tmp_path):
    cache = tmp_path / "cache"
    key = cache / "0123abcd"
    key.mkdir(parents=True)
    dead_pid = subprocess.Popen(["true"])  # a pid that has exited
    dead_pid.wait()
    host = outputs.owner_tag().split("@", 1)[1]
    stale = key / f".build-{dead_pid.pid}@{host}-abc123"
    live = key / f".build-{os.getpid()}@{host}-def456"
    foreign = key / ".build-123@otherhost-xyz"
    old_untagged, new_untagged = key / ".build-olduntag", key / ".build-newuntag"
    partial = key / f".softpinn_x.so.partial-{dead_pid.pid}@{host}-q1w2e3"
    for p in (stale, live, foreign, old_untagged, new_untagged):
        p.mkdir()
    partial.write_text("half a library")
    hour_ago = time.time() - 2 * 3600
    os.utime(old_untagged, (hour_ago, hour_ago))
    removed = codegen.remove_stale_builds(cache)
    assert sorted(removed) == sorted([stale, old_untagged, partial])
    assert live.is_dir() and foreign.is_dir() and new_untagged.is_dir()
