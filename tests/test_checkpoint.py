"""Atomic files and run directories (learn/_checkpoint.py)."""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np
import pytest

from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt


def test_atomic_write_replaces_and_leaves_no_temp(tmp_path):
    p = tmp_path / "a.json"
    ckpt.atomic_write_json(p, {"x": 1})
    ckpt.atomic_write_json(p, {"x": 2})
    assert ckpt.read_json(p) == {"x": 2}
    assert os.listdir(tmp_path) == ["a.json"]


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    p = tmp_path / "model.eqx"
    ckpt.atomic_write_bytes(p, b"good")

    def boom(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        ckpt.atomic_write_bytes(p, b"half-written")
    monkeypatch.undo()
    assert p.read_bytes() == b"good"
    assert os.listdir(tmp_path) == ["model.eqx"]


def test_tree_round_trip_with_header(tmp_path):
    tree = {"w": jnp.arange(6.0).reshape(2, 3), "b": (jnp.ones(2, jnp.float32), jnp.int32(7))}
    ckpt.save_tree(tmp_path / "t.eqx", tree, {"epoch": 3, "best": [0.5]})
    like = {"w": jnp.zeros((2, 3)), "b": (jnp.zeros(2, jnp.float32), jnp.int32(0))}
    header, back = ckpt.load_tree(tmp_path / "t.eqx", like)
    assert header == {"epoch": 3, "best": [0.5]}
    assert ckpt.read_header(tmp_path / "t.eqx") == header
    np.testing.assert_array_equal(back["w"], tree["w"])
    assert back["b"][0].dtype == jnp.float32 and int(back["b"][1]) == 7
    with pytest.raises(UserError, match="does not match the model"):
        ckpt.load_tree(tmp_path / "t.eqx", {"w": jnp.zeros((3, 3)), "b": like["b"]})
    (tmp_path / "junk.eqx").write_bytes(b"\xff\xfe not json\n")
    with pytest.raises(UserError, match="not a softpinn checkpoint"):
        ckpt.read_header(tmp_path / "junk.eqx")
    with pytest.raises(UserError, match="no such file"):
        ckpt.load_tree(tmp_path / "none.eqx", like)


def test_history_round_trip(tmp_path):
    rows = [
        {"epoch": 0, "train_loss": 0.1, "test_loss": 0.2, "seconds": 0.0, "phase": "adamw"},
        {
            "epoch": 1,
            "train_loss": 1 / 3,
            "test_loss": float("inf"),
            "seconds": 1.25,
            "phase": "lbfgs",
        },
    ]
    ckpt.write_history(tmp_path / "history.csv", rows)
    assert ckpt.read_history(tmp_path / "history.csv") == rows
    header = (tmp_path / "history.csv").read_text().splitlines()[0]
    assert header == "epoch,train_loss,test_loss,seconds,phase"


def test_prepare_run_dir(tmp_path):
    out = tmp_path / "run"
    assert ckpt.prepare_run_dir(out) == out and out.is_dir()
    assert ckpt.prepare_run_dir(out) == out  # empty: fine
    (out / "config.json").write_text("{}")
    (out / "model.eqx").write_bytes(b"x")
    (out / "seed-3").mkdir()
    (out / "seed-3" / "config.json").write_text("{}")
    (out / "mine.txt").write_text("user file")
    with pytest.raises(UserError, match="already exists and is not empty; use --force"):
        ckpt.prepare_run_dir(out)
    assert ckpt.prepare_run_dir(out, resume=True) == out
    ckpt.prepare_run_dir(out, force=True)
    assert sorted(os.listdir(out)) == ["mine.txt"]
    with pytest.raises(UserError, match="holds no run to resume"):
        ckpt.prepare_run_dir(out, resume=True)
    f = tmp_path / "file"
    f.write_text("")
    with pytest.raises(UserError, match="is a file"):
        ckpt.prepare_run_dir(f)


def test_written_files_follow_the_umask(tmp_path):
    """Run files are readable as any file the user writes (umask 022: 0644), not mkstemp's
    0600, which hid runs from colleagues on a shared machine."""
    import stat

    old = os.umask(0o022)
    try:
        path = ckpt.atomic_write_bytes(tmp_path / "x.bin", b"data")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
