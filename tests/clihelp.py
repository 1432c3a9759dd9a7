"""The ``softpinn`` command line run in-process by the tests, and the one-line error check every
bad-input test makes (exit 2, ``softpinn: error: ...`` on one line, no traceback)."""

from __future__ import annotations


def run_cli(capsys, *argv):
    """(exit status, stdout, stderr) of ``softpinn ARGV`` through the real ``main`` (argparse's
    own errors exit through SystemExit: its code is the status)."""
    from softpinn.bridge import cli

    try:
        status = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        status = exc.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def one_line_error(capsys, *argv) -> str:
    """stderr of ``softpinn ARGV``, asserted to be a one-line user error with exit status 2."""
    status, _, err = run_cli(capsys, *argv)
    assert status == 2 and err.startswith("softpinn: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    return err
