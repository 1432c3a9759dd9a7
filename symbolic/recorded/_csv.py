"""Recorded trajectories in CSV files (``docs/import.md``): reading and validation.

:func:`read_recordings` reads one or more CSV files with a header row and returns one
:class:`Recording` per trajectory (a file is one trajectory, or several told apart by an integer
``traj`` column). Columns: ``t`` [s] (strictly increasing within a trajectory, not necessarily
uniform), inputs ``u0 .. u{m-1}``, and the state: configurations ``q0 .. q{n-1}`` (optionally
velocities ``qd0 .. qd{n-1}``), or the tip orientation as a quaternion ``qw, qx, qy, qz`` or as
``roll, pitch, yaw`` [rad]. Other columns are ignored (and listed). Blank lines and lines that
start with ``#`` are skipped.

Every mistake is one line naming the file, the line (the header is line 1 when nothing precedes
it; the number an editor shows) and the column: a missing column, a wrong count of inputs or of
q columns for the model, an empty file, something that is not a CSV, a value that is not a
number, NaN or inf, time that does not increase, a ``traj`` value that is not an integer.
"""

from __future__ import annotations

import csv
import hashlib
import io
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from softpinn.errors import UserError
from softpinn.symbolic._outputs import count_of

ORIENTATIONS = ("quaternion", "rpy")
ORIENTATION_COLUMNS = {"quaternion": ("qw", "qx", "qy", "qz"), "rpy": ("roll", "pitch", "yaw")}
#: a quaternion whose norm is further than this from 1 is refused
QUATERNION_TOLERANCE = 1e-2


class RecordingError(UserError):
    """A recording that cannot be imported; the message names the file, line and column."""


@dataclass
class Recording:
    """One recorded trajectory: times (N,), inputs (N, m), and the state columns it has."""

    file: str
    traj: int | None  # the value of the file's traj column, if it has one
    lines: np.ndarray  # (N,) line numbers in the file
    t: np.ndarray
    u: np.ndarray
    q: np.ndarray | None = None  # (N, n) configurations
    qd: np.ndarray | None = None  # (N, n) velocities, when recorded
    orientation: np.ndarray | None = None  # (N, 4) quaternions or (N, 3) roll, pitch, yaw

    @property
    def where(self) -> str:
        what = f"{self.file} (trajectory {self.traj})" if self.traj is not None else self.file
        first, last = int(self.lines[0]), int(self.lines[-1])
        return f"{what}, line {first}" if first == last else f"{what}, lines {first}-{last}"


@dataclass
class CsvFile:
    """A CSV file's header and its data rows as strings, with their line numbers."""

    path: str
    columns: list[str]
    rows: list[list[str]]
    lines: list[int]
    sha256: str
    ignored: list[str] = field(default_factory=list)

    def column(self, name: str) -> np.ndarray:
        """A column as floats; a cell that is not a number, NaN or inf is refused by line."""
        j = self.columns.index(name)
        cells = [r[j].strip() for r in self.rows]
        try:
            values = np.array(cells, dtype=float)
        except ValueError:
            values = None
        for i, cell in enumerate(cells):
            if values is not None and np.isfinite(values[i]):
                continue
            if cell == "":
                self.fail(self.lines[i], name, "empty value")
            try:
                v = float(cell)
            except ValueError:
                self.fail(self.lines[i], name, f"not a number: {cell!r}")
            if not np.isfinite(v):
                self.fail(self.lines[i], name, f"{cell} (values must be finite)")
        return values

    def fail(self, line: int | None, column: str | None, message: str):
        where = self.path
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        raise RecordingError(f"{where}: {message}")


def read_csv(path: str | Path) -> CsvFile:
    """Read a CSV file with a header row (comma-separated, UTF-8); see the module docstring."""
    name = str(path)
    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{name}: no such file")
    raw = p.read_bytes()
    if b"\0" in raw[:65536]:
        raise RecordingError(f"{name}: not a CSV file (binary data)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{name}: not a CSV file (not UTF-8 text: {exc.reason} at byte "
                             f"{exc.start})") from None
    header: list[str] | None = None
    rows: list[list[str]] = []
    lines: list[int] = []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        for fields in reader:
            line = reader.line_num
            if not fields or all(f.strip() == "" for f in fields) or fields[0].lstrip()[:1] == "#":
                continue
            if header is None:
                header = [f.strip() for f in fields]
                header_line = line
                continue
            if len(fields) != len(header):
                raise RecordingError(f"{name}, line {line}: {len(fields)} fields, the header "
                                     f"(line {header_line}) has {len(header)}")
            rows.append(fields)
            lines.append(line)
    except csv.Error as exc:
        raise RecordingError(f"{name}, line {reader.line_num}: not a CSV file ({exc})") from None
    if header is None:
        raise RecordingError(f"{name}: empty file (expected a header row such as 't,u0,q0')")
    if len(header) == 1 and re.search(r"[;\t|]", header[0]):
        raise RecordingError(f"{name}, line {header_line}: not a CSV file: the header "
                             f"{header[0]!r} has one column (columns are separated by commas)")
    for j, col in enumerate(header):
        if col == "":
            raise RecordingError(f"{name}, line {header_line}: column {j + 1} has no name")
        if _is_number(col):
            raise RecordingError(f"{name}, line {header_line}: expected a header row of column "
                                 f"names, got the number {col!r} in column {j + 1}")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise RecordingError(f"{name}, line {header_line}, column '{dup[0]}': the header names "
                             "it twice")
    if not rows:
        raise RecordingError(f"{name}: no data rows after the header (line {header_line})")
    return CsvFile(name, header, rows, lines, hashlib.sha256(raw).hexdigest())


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _indexed(columns: Sequence[str], prefix: str) -> dict[int, str]:
    pattern = re.compile(rf"{prefix}(\d+)")
    out = {}
    for c in columns:
        m = pattern.fullmatch(c)
        if m:
            out[int(m.group(1))] = c
    return out


def _check_indexed(f: CsvFile, prefix: str, count: int, what: str, model: str, *,
                   optional: bool = False) -> list[str] | None:
    """The columns ``prefix0 .. prefix{count-1}``: all present (or, if ``optional``, none), and
    no ``prefix{k}`` with k >= count."""
    have = _indexed(f.columns, prefix)
    names = f"{prefix}0 .. {prefix}{count - 1}" if count > 1 else f"{prefix}0"
    extra = sorted(k for k in have if k >= count)
    if extra:
        has = (f"m = {count_of(count, 'input')}" if prefix == "u"
               else f"n = {count_of(count, 'coordinate')}")
        expect = f" ({names})" if count else ""
        f.fail(None, have[extra[0]], f"model {model} has {has}{expect}; the file has "
               f"{max(have) + 1} {what} columns")
    if optional and not have:
        return None
    missing = [k for k in range(count) if k not in have]
    if missing:
        has = (f"m = {count_of(count, 'input')}" if prefix == "u"
               else f"n = {count_of(count, 'coordinate')}")
        f.fail(None, f"{prefix}{missing[0]}", f"missing column (model {model} has {has}: "
               f"{names}; the header has {', '.join(f.columns)})")
    return [have[k] for k in range(count)]


def read_recordings(
    paths: Sequence[str | Path],
    *,
    n: int,
    m: int,
    model: str = "the model",
    orientation: str | None = None,
) -> tuple[list[Recording], list[CsvFile]]:
    """Read and validate the files; one :class:`Recording` per trajectory, in file order and,
    within a file, in order of first appearance of each ``traj`` value."""
    if not paths:
        raise RecordingError("no recording files given")
    if orientation is not None and orientation not in ORIENTATIONS:
        raise RecordingError(f"orientation: expected one of {', '.join(ORIENTATIONS)}, got "
                             f"{orientation!r}")
    recordings, files = [], []
    for path in paths:
        f = read_csv(path)
        files.append(f)
        recordings.extend(_recordings_of(f, n=n, m=m, model=model, orientation=orientation))
    return recordings, files


def _recordings_of(f: CsvFile, *, n, m, model, orientation) -> list[Recording]:
    if "t" not in f.columns:
        f.fail(None, "t", f"missing column (time in seconds; the header has "
               f"{', '.join(f.columns)})")
    ucols = _check_indexed(f, "u", m, "input", model)
    used = ["t", *ucols]
    if orientation is None:
        if "q0" not in f.columns:
            for kind, cols in ORIENTATION_COLUMNS.items():
                if all(c in f.columns for c in cols):
                    f.fail(None, "q0", f"missing column (the file has {', '.join(cols)}: to "
                           f"import tip orientation, add --orientation {kind})")
        qcols = _check_indexed(f, "q", n, "q", model)
        qdcols = _check_indexed(f, "qd", n, "qd", model, optional=True)
        used += qcols + (qdcols or [])
    else:
        ocols = list(ORIENTATION_COLUMNS[orientation])
        for c in ocols:
            if c not in f.columns:
                f.fail(None, c, f"missing column (--orientation {orientation} reads "
                       f"{', '.join(ocols)})")
        used += ocols
    has_traj = "traj" in f.columns
    if has_traj:
        used.append("traj")
    f.ignored = [c for c in f.columns if c not in used]
    data = {c: f.column(c) for c in used}
    lines = np.asarray(f.lines)
    if has_traj:
        tr = data["traj"]
        bad = np.flatnonzero(tr != np.round(tr))
        if bad.size:
            f.fail(int(lines[bad[0]]), "traj", f"trajectory ids must be integers, got "
                   f"{f.rows[bad[0]][f.columns.index('traj')].strip()!r}")
        tr = tr.astype(np.int64)
        ids = list(dict.fromkeys(tr.tolist()))
        groups = [(i, np.flatnonzero(tr == i)) for i in ids]
    else:
        groups = [(None, np.arange(len(lines)))]
    out = []
    for tid, rows in groups:
        t = data["t"][rows]
        back = np.flatnonzero(np.diff(t) <= 0)
        if back.size:
            k = back[0] + 1
            where = f" (trajectory {tid})" if tid is not None else ""
            f.fail(int(lines[rows[k]]), "t", f"time {t[k]:g} s is not after the previous "
                   f"sample's {t[k - 1]:g} s{where}: time must increase within a trajectory")
        rec = Recording(
            file=f.path,
            traj=tid,
            lines=lines[rows],
            t=t,
            u=np.stack([data[c][rows] for c in ucols], 1) if m else np.zeros((len(rows), 0)),
        )
        if orientation is None:
            rec.q = np.stack([data[c][rows] for c in qcols], 1)
            if qdcols:
                rec.qd = np.stack([data[c][rows] for c in qdcols], 1)
        else:
            rec.orientation = np.stack([data[c][rows] for c in ORIENTATION_COLUMNS[orientation]],
                                       1)
            if orientation == "quaternion":
                norm = np.linalg.norm(rec.orientation, axis=1)
                bad = np.flatnonzero(np.abs(norm - 1) > QUATERNION_TOLERANCE)
                if bad.size:
                    f.fail(int(rec.lines[bad[0]]), "qw", f"quaternion (qw, qx, qy, qz) has norm "
                           f"{norm[bad[0]]:.4g}; expected a unit quaternion")
        out.append(rec)
    return out
