"""``softpinn cache``: what softpinn keeps between runs, and --clear removing only that."""

from __future__ import annotations

import json

from softpinn.bridge.cli import main
from softpinn.learn import jitcache


def _fill(tmp_path, monkeypatch):
    code, jit = tmp_path / "code", tmp_path / "jit"
    monkeypatch.setenv("SOFTPINN_CACHE", str(code))
    monkeypatch.setenv("SOFTPINN_JIT_CACHE", str(jit))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    for name in ("0794cae7efe3dddf0e4b17bb", "kernel_033ca13460e6821e13689499", ".build-x-1"):
        (code / name).mkdir(parents=True)
        (code / name / "lib.so").write_bytes(b"x" * 1000)
    (code / "notes.txt").write_text("mine")  # a user's files in the folder they chose
    (code / "mydata").mkdir()
    here = jitcache.cache_folder()
    here.mkdir(parents=True)
    for name in ("jit_f-ab12-cache", "jit_g-cd34-cache"):
        (here / name).write_bytes(b"y" * 500)
        (here / name.replace("-cache", "-atime")).write_bytes(b"t" * 8)
    (here / "probe.json").write_text(json.dumps({"ok": True, "why": "loaded"}))
    (here / "probe-123").mkdir()  # a probe's leftovers (a process killed while probing)
    other = jit / "0123456789abcdef"
    other.mkdir()
    (other / "jit_h-ef56-cache").write_bytes(b"z" * 300)
    (jit / "readme.txt").write_text("mine too")
    return code, jit, here, other


def test_cache_lists_both_caches(tmp_path, monkeypatch, capsys):
    code, jit, here, other = _fill(tmp_path, monkeypatch)
    assert main(["cache", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["code"] == {"folder": str(code), "libraries": 2, "bytes": 3000}
    g = record["programs"]
    probe = (here / "probe.json").stat().st_size
    assert g["folder"] == str(here) and g["programs"] == 2 and g["bytes"] == 2 * 508 + probe
    assert g["other_folders"] == 1 and g["other_bytes"] == 300
    assert g["probe"].startswith("checked")
    assert main(["cache"]) == 0
    text = capsys.readouterr().out
    assert "2 libraries" in text and "2 programs" in text and "1 other machines'" in text


def test_clear_removes_only_softpinns_files(tmp_path, monkeypatch, capsys):
    code, jit, here, other = _fill(tmp_path, monkeypatch)
    assert main(["cache", "--clear"]) == 0
    assert "removed 2 libraries" in capsys.readouterr().out
    assert sorted(p.name for p in code.iterdir()) == ["mydata", "notes.txt"]
    assert sorted(p.name for p in jit.iterdir()) == ["readme.txt"]  # emptied folders go too
    assert main(["cache", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["code"]["libraries"] == 0 and record["programs"]["programs"] == 0


def test_cache_off_and_a_users_jax_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SOFTPINN_CACHE", str(tmp_path / "code"))
    monkeypatch.setenv("SOFTPINN_JIT_CACHE", "off")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "theirs"))
    assert main(["cache"]) == 0
    text = capsys.readouterr().out
    assert "XLA programs: off" in text and "0 libraries" in text
    assert f"JAX_COMPILATION_CACHE_DIR={tmp_path / 'theirs'} is set" in text


def test_clear_says_what_it_could_not_remove(tmp_path, monkeypatch, capsys):
    from softpinn.bridge.cli import _cache_run as cache

    _fill(tmp_path, monkeypatch)

    def refuse(path):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(cache, "_remove", refuse)
    assert main(["cache", "--clear"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("softpinn: error: could not remove 10 of the cached entries, e.g. ")
    assert err.endswith(": Permission denied") and "\n" not in err
