"""Checksums (issue 15): every model and checkpoint file carries the sha256 of its content,
verified on load, so that a corrupted file is refused with one line instead of predicting
garbage; every file written into a run directory is listed in its manifest."""

from __future__ import annotations

import jax.numpy as jnp
import pytest
from datagen import blackbox_train_config, make_dataset

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._rundir import load_run
from softpinn.learn._train import train


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("sum")
    data = make_dataset(base / "msd.npz", trajectories=5, duration=4.0)
    train(data, blackbox_train_config(), base / "run")
    return base / "run", data


def _flip(path, where):
    b = bytearray(path.read_bytes())
    b[where] ^= 0x01
    path.write_bytes(bytes(b))


def test_flipped_byte_in_the_leaves_is_refused(tmp_path):
    tree = {"w": jnp.arange(6.0)}
    path = ckpt.save_tree(tmp_path / "t.eqx", tree, {"epoch": 1})
    assert "sha256" in path.read_bytes().split(b"\n")[0].decode()
    _flip(path, len(path.read_bytes()) - 3)
    with pytest.raises(UserError, match="t.eqx: checksum mismatch, the file is corrupted"):
        ckpt.load_tree(path, {"w": jnp.zeros(6)})


def test_changed_header_is_refused(tmp_path):
    path = ckpt.save_tree(tmp_path / "t.eqx", {"w": jnp.arange(3.0)}, {"epoch": 1})
    path.write_bytes(path.read_bytes().replace(b'"epoch": 1', b'"epoch": 7'))
    with pytest.raises(UserError, match="checksum mismatch"):
        ckpt.load_tree(path, {"w": jnp.zeros(3)})


def test_file_without_checksum_still_loads(tmp_path):
    """Runs written before checksums existed stay loadable."""
    import io
    import json

    import equinox as eqx

    buf = io.BytesIO()
    eqx.tree_serialise_leaves(buf, {"w": jnp.arange(3.0)})
    (tmp_path / "old.eqx").write_bytes(json.dumps({"epoch": 2}).encode() + b"\n" + buf.getvalue())
    header, tree = ckpt.load_tree(tmp_path / "old.eqx", {"w": jnp.zeros(3)})
    assert header == {"epoch": 2} and float(tree["w"][2]) == 2.0


def test_corrupted_model_eqx_gives_one_line(run, tmp_path, capsys):
    import shutil

    src, data = run
    bad = tmp_path / "bad"
    shutil.copytree(src, bad)
    path = bad / "model.eqx"
    _flip(path, len(path.read_bytes()) // 2 + 40)
    with pytest.raises(UserError, match="model.eqx: checksum mismatch"):
        load_run(bad)
    assert main(["predict", str(bad), str(data), "--horizon", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "model.eqx: checksum mismatch" in err[0]
    _flip(bad / "checkpoint.eqx", len((bad / "checkpoint.eqx").read_bytes()) - 5)
    assert main(["train", str(data), "--out", str(bad), "--resume", "--quiet"]) == 2
    assert "checkpoint.eqx: checksum mismatch" in capsys.readouterr().err


def test_manifest_lists_every_written_file_with_its_sha256(run):
    import hashlib

    src, _ = run
    files = ckpt.read_manifest(src)
    on_disk = {p.name for p in src.iterdir() if p.name != ckpt.MANIFEST}
    assert set(files) == on_disk == {"config.json", "model.eqx", "checkpoint.eqx",
                                     "history.csv", "metrics.json", "loss.png"}
    for name, digest in files.items():
        assert hashlib.sha256((src / name).read_bytes()).hexdigest() == digest
