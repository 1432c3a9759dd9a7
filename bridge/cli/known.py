"""``--known-input`` of ``softpinn train`` and ``sweep``: a fixed input matrix A(q) (the known
actuator model of Section VI-B) from a constant matrix file, a spec's exact A(q) or a program
written by ``softpinn derive --programs``, as the ``known_input`` text of
:class:`softpinn.learn.ModelConfig`, with one-line errors for what does not fit the data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from softpinn.bridge.exact.serialize import spec_known_input
from softpinn.errors import UserError
from softpinn.learn import PROGRAM_FORMAT, known_input_text, parse_known_input


def known_input(source: str, n: int, m: int) -> str:
    """``--known-input``: the ``known_input`` text of a constant matrix file (.npy, or .json
    with a list of rows) or of a symbolic model's exact A(q) (a preset name or a spec path),
    checked against the data's n coordinates and m inputs."""
    path = Path(source)
    if path.suffix in (".npy", ".json"):
        if not path.is_file():
            raise UserError(f"--known-input: no such file {source}")
        try:
            if path.suffix == ".npy":
                value = np.load(path, allow_pickle=False)
            else:
                value = json.loads(path.read_text("utf-8"))
            program = isinstance(value, dict) and value.get("format") == PROGRAM_FORMAT
            a = None if program else np.asarray(value, dtype=np.float64)
        except (OSError, ValueError, TypeError) as err:
            raise UserError(f"--known-input: {source} is not a numeric matrix "
                            f"({str(err).splitlines()[0] if str(err) else type(err).__name__})"
                            ) from None
        if a is None:
            return _known_program(source, value, n, m)
        if a.shape != (n, m):
            raise UserError(f"--known-input: {source} holds a matrix of shape {a.shape}; the "
                            f"data need n x m = {n} x {m}")
        if not np.all(np.isfinite(a)):
            raise UserError(f"--known-input: {source} holds NaN or inf")
        return known_input_text(a)

    try:
        text, sn, sm = spec_known_input(source)
    except UserError as err:
        raise UserError(f"--known-input: {err}") from None
    if (sn, sm) != (n, m):
        raise UserError(f"--known-input: model {source} has n = {sn} coordinates and m = {sm} "
                        f"inputs; the data have n = {n}, m = {m}")
    return text


def _known_program(source: str, data: dict, n: int, m: int) -> str:
    """``--known-input A.program.json``: A(q) as a replayable program (``softpinn derive
    --programs``), checked to be a function of the data's n coordinates with an n x m output."""
    outs = data.get("outputs")
    named = outs[0].get("name") if isinstance(outs, list) and len(outs) == 1 and isinstance(
        outs[0], dict) else None
    if named in ("M", "M_inv", "D", "G"):  # derive's other functions of q alone
        raise UserError(f"--known-input: {source} is the program of {named}(q), not of the input "
                        "matrix A(q) (derive writes it as A.program.json)")
    text = known_input_text(data)
    try:
        parse_known_input(text, n, m)
    except UserError as err:
        raise UserError(f"--known-input: {source}: {err}") from None
    return text
