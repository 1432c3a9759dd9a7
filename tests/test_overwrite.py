"""Nothing of the user's destroyed (issue 15): ``predict --plot`` replaces only a plot softpinn
wrote (or with --force); ``train --force`` removes only the files its manifest lists, never the
user's own files, PNGs included."""

from __future__ import annotations

import pytest
from datagen import blackbox_train_config, make_dataset

from softpinn.bridge.cli import main
from softpinn.errors import UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._predict import predict
from softpinn.learn._train import train
from softpinn.learn.plots import written_by_softpinn


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("ow")
    data = make_dataset(base / "msd.npz", trajectories=5, duration=4.0)
    train(data, blackbox_train_config(), base / "run")
    return base / "run", data


def test_plot_refuses_files_softpinn_did_not_write(run, tmp_path, capsys):
    out, data = run
    before = {p: p.read_bytes() for p in (data, out / "model.eqx")}
    for target in before:
        with pytest.raises(UserError, match="exists and was not written by softpinn"):
            predict(out, data, horizon=1.0, plot=target)
        assert main(["predict", str(out), str(data), "--horizon", "1", "--plot",
                     str(target)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("softpinn: error: --plot: ")
    assert {p: p.read_bytes() for p in before} == before
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"\x89PNG\r\n\x1a\n not softpinn's")
    with pytest.raises(UserError, match="not written by softpinn"):
        predict(out, data, horizon=1.0, plot=mine)


def test_plot_replaces_its_own_png_and_force(run, tmp_path):
    out, data = run
    png = tmp_path / "roll.png"
    predict(out, data, horizon=1.0, plot=png)
    assert written_by_softpinn(png)
    predict(out, data, horizon=0.5, plot=png)  # its own plot: replaced
    other = tmp_path / "other.txt"
    other.write_text("x")
    assert main(["predict", str(out), str(data), "--horizon", "1", "--plot", str(other),
                 "--force"]) == 0
    assert written_by_softpinn(other)


def test_plot_into_a_file_or_folder_is_one_line(run, tmp_path):
    out, data = run
    with pytest.raises(UserError, match=r"plot: .*msd.npz is a file, not a folder"):
        predict(out, data, horizon=1.0, plot=data / "x.png")
    with pytest.raises(UserError, match="is a folder, not a file"):
        predict(out, data, horizon=1.0, plot=tmp_path)


def test_force_removes_only_what_softpinn_wrote(run, tmp_path):
    _, data = run
    out = tmp_path / "run"
    train(data, blackbox_train_config(epochs=2, seeds=2, ensemble="vmap"), out)
    (out / "figure.png").write_bytes(b"user's own figure")
    (out / "history.csv.bak").write_text("user")
    (out / "seed-0" / "notes.txt").write_text("user")
    assert "seed-0" in {p.name for p in out.iterdir()}
    train(data, blackbox_train_config(epochs=2), out, force=True)
    assert (out / "figure.png").read_bytes() == b"user's own figure"
    assert (out / "history.csv.bak").read_text() == "user"
    assert sorted(p.name for p in (out / "seed-0").iterdir()) == ["notes.txt"]
    assert not (out / "seed-1").exists()
    assert set(ckpt.read_manifest(out)) == {"config.json", "model.eqx", "checkpoint.eqx",
                                            "history.csv", "metrics.json", "loss.png"}


def test_out_inside_a_file_or_unwritable_is_one_line(run, tmp_path, capsys):
    _, data = run
    with pytest.raises(UserError, match=r"msd.npz is a file, not a folder"):
        train(data, blackbox_train_config(), data / "run")
    blocked = tmp_path / "ro"
    blocked.mkdir()
    blocked.chmod(0o500)
    try:
        import os

        if os.access(blocked, os.W_OK):  # root ignores permissions: use a path under /proc
            target = "/proc/softpinn-run"
        else:
            target = str(blocked / "run")
        assert main(["train", str(data), "--model", "blackbox", "--out", target,
                     "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "cannot write there" in err[0]
    finally:
        blocked.chmod(0o700)
