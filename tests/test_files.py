"""The one atomic write and the one strict JSON writer (``softpinn.files``): every writer gets a
temporary file of its own (two writers of the same file at once never share one), and the JSON
writer applies its NaN rule (null in files, refused where a value must be finite, ``Infinity``
kept only where a caller names that exception)."""

from __future__ import annotations

import enum
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from softpinn import files
from softpinn.errors import UserError

NAN, INF = float("nan"), float("inf")


def _replace_together(monkeypatch, writers: int = 2) -> list[str]:
    """Make ``os.replace`` wait until ``writers`` writers have all written their temporary file
    (so that they overlap for sure); return the temporary names they renamed."""
    barrier = threading.Barrier(writers, timeout=30)
    real = os.replace
    seen: list[str] = []

    def replace(src, dst):
        seen.append(os.fspath(src))
        barrier.wait()
        return real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    return seen


def _concurrently(*fns) -> list[BaseException]:
    errors: list[BaseException] = []

    def run(fn):
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(fn,)) for fn in fns]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    return errors


@pytest.mark.parametrize("writer", ["atomic_write", "write_json", "learn"])
def test_two_writers_of_one_file_never_share_a_temporary_file(tmp_path, monkeypatch, writer):
    """Two writers of the same file at once, both past writing their temporary file before
    either renames it: with a fixed temporary name (``.name.tmp``, as report.md, the control
    comparison and the task stages had) the second rename finds nothing, or installs a mix."""
    path = tmp_path / "out" / "report.md"
    payloads = ["a" * 100_000, "b" * 100_000]
    if writer == "atomic_write":
        write = files.atomic_write
    elif writer == "write_json":
        def write(p, text):
            files.write_json(p, {"text": text})
    else:
        from softpinn.learn import atomic_write_text as write
    seen = _replace_together(monkeypatch)
    errors = _concurrently(*(lambda t=t: write(path, t) for t in payloads))
    monkeypatch.undo()
    assert errors == []
    assert len(seen) == 2 and seen[0] != seen[1], seen
    text = path.read_text()
    if writer == "write_json":
        text = json.loads(text)["text"]
    assert text in payloads  # one writer's file, whole
    assert sorted(p.name for p in path.parent.iterdir()) == ["report.md"]  # no temporary left


@pytest.mark.parametrize("module", ["softpinn.bridge.control.report", "softpinn.bridge.report.task",
                                    "softpinn.bridge.report.experiment"])
def test_report_writers_use_the_one_atomic_write(module):
    """report.md of a task, an experiment and a control comparison: written through
    :func:`softpinn.files.atomic_write` (they had fixed ``.report.md.tmp`` names)."""
    import importlib

    assert importlib.import_module(module).atomic_write is files.atomic_write


def test_temporary_names_hold_the_pid_and_a_random_part(tmp_path):
    target = tmp_path / "results.json"
    a, b = files.partial_path(target), files.partial_path(target)
    assert a != b and a.parent == b.parent == tmp_path
    tag = f".results.json.partial-{os.getpid()}@"
    assert a.name.startswith(tag) and b.name.startswith(tag)
    code = "from softpinn import files; import sys; print(files.partial_path(sys.argv[1]).name)"
    other = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True,
                           text=True, check=True).stdout.strip()
    assert other.startswith(".results.json.partial-") and not other.startswith(tag)


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = files.atomic_write(tmp_path / "a.txt", "old")

    def boom(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        files.atomic_write(path, "new")
    monkeypatch.undo()
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["a.txt"]


def test_a_dead_writers_temporary_file_is_stale_a_live_ones_not(tmp_path):
    done = subprocess.Popen(["true"])
    done.wait()
    host = files.owner_tag().split("@", 1)[1]
    dead = tmp_path / f".x.json.partial-{done.pid}@{host}-0a1b2c3d"
    alive = tmp_path / f".x.json.partial-{os.getpid()}@{host}-0a1b2c3d"
    dead.write_text("half")
    alive.write_text("being written")
    assert files.remove_stale_partials(tmp_path / "x.json") == [dead]
    assert alive.exists()


# ------------------------------------------------------------------------------- the NaN rule


class Kind(enum.Enum):
    A = "a"


def test_files_hold_null_for_nan_and_inf(tmp_path):
    obj = {"a": NAN, "b": [1.0, INF], "c": {"d": -INF}, "e": np.float32("nan"),
           "f": np.array([1.0, np.inf]), "g": (np.int64(2), np.float64(0.5)), "h": Kind.A,
           "i": Path("x") / "y"}
    path = files.write_json(tmp_path / "r.json", obj)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"a": None, "b": [1.0, None], "c": {"d": None}, "e": None,
                                "f": [1.0, None], "g": [2, 0.5], "h": "a", "i": "x/y"}


def test_refuse_names_the_first_non_finite_value():
    with pytest.raises(files.NonFiniteError, match=r"^M_inv\[1\]\[0\] is not a finite"):
        files.json_text({"M_inv": [[1.0, 0.0], [NAN, 1.0]]}, nonfinite=files.REFUSE)
    with pytest.raises(files.NonFiniteError, match=r"^value is not"):
        files.json_text(INF, nonfinite=files.REFUSE)
    with pytest.raises(UserError, match=r"^meta: simulation\.rtol is not a finite number"):
        from softpinn.symbolic import dumps

        dumps({"simulation": {"rtol": np.float64("nan")}}, what="meta")


def test_keep_is_the_named_exception():
    text = files.json_text({"mean": INF, "x": NAN}, nonfinite=files.KEEP, indent=None, end="")
    assert text == '{"mean": Infinity, "x": NaN}'
    with pytest.raises(ValueError, match="nonfinite: expected one of"):
        files.json_text({}, nonfinite="zero")


@pytest.mark.parametrize(("indent", "end"), [(2, "\n"), (1, ""), (1, "\n"), (None, "")])
def test_finite_files_are_written_as_json_dumps_wrote_them(indent, end):
    """The writer changes no byte of a file softpinn wrote before it (finite numbers)."""
    obj = {"z": 1, "a": [0.1, 1e-300, 2.5e10, -0.0, True, None], "m": {"k": "é ±", "n": []},
           "t": (1, 2), 3: "int key"}
    assert files.json_text(obj, indent=indent, end=end) == json.dumps(obj, indent=indent) + end


def test_every_json_writer_applies_the_rule(tmp_path):
    """learn's run files and bridge's results: null; the task stages: Infinity, given back."""
    from softpinn.bridge.base.outputs import to_jsonable
    from softpinn.learn import atomic_write_json

    atomic_write_json(tmp_path / "m.json", {"loss": NAN})
    assert (tmp_path / "m.json").read_text() == '{\n  "loss": null\n}\n'
    assert to_jsonable({1: np.array([INF, 2.0]), "k": Kind.A}) == {"1": [None, 2.0], "k": "a"}
    from softpinn.bridge.tasks.stages import write_json

    write_json(tmp_path / "done.json", {"mean": INF, "n": np.int64(3)})
    assert (tmp_path / "done.json").read_text() == '{\n  "mean": Infinity,\n  "n": 3\n}'
    assert json.loads((tmp_path / "done.json").read_text())["mean"] == INF
