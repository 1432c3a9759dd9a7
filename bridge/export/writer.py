"""``export_run``: a trained run directory -> CasADi Functions, generated C and metadata on disk.

The C compile runs before anything is written to the output directory: one that runs past
``compile_timeout`` (default 600 s) or fails leaves the directory as it was; C over
``LARGE_SOURCE_MB`` compiles at -O0 (several times faster to build, slower to run). The output
directory holds

* ``model.casadi`` (the Function ``qdd`` with inputs ``q``, ``qd``, ``u``) and one
  ``<name>.casadi`` per Function (``qdd``, ``field``, ``step``, and for physics models ``M``,
  ``M_inv``, ``G``, ``D``, ``A``); load any of them with ``casadi.Function.load``;
* ``model.c`` and ``model.h``: the same Functions as C (CasADi's code generator, one C function
  per name with the usual ``<name>_work``/``<name>_n_in``... companions), and ``model.so``, that C
  compiled through the project's code cache (:func:`softpinn.symbolic.compile_functions`; absent
  without a C compiler or with ``compile=False``: the ``.casadi`` Functions need no library, they
  run in CasADi's virtual machine, and ``softpinn control`` compiles its own solver from them);
* ``model.json``: kind, sizes, state and coordinate names, units, the training data and
  configuration, the integrator of ``step``, the run's actuator (``actuator``: numbers, text
  and what to feed the model), a checksum of the run's files, the versions, and ``sha256``:
  the checksum of every other file written here, which every loader checks
  (:mod:`.verify`);
* for a run with an actuator (issue 43 item 2) also ``actuator.casadi`` and
  ``actuator_step.casadi`` (:mod:`.actuator`): the model's ``u`` is the actuator's output.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from softpinn._version import __version__
from softpinn.bridge.base import outputs
from softpinn.bridge.export.actuator import actuator_functions, actuator_metadata
from softpinn.bridge.export.dynamics import export_functions
from softpinn.bridge.export.params import model_params
from softpinn.bridge.export.verify import CHECKSUMS, file_checksums, read_export
from softpinn.errors import UserError
from softpinn.learn import load_run, run_actuator
from softpinn.symbolic import DEFAULT_FLAGS, DEFAULT_TIMEOUT, CompilerTimeout, compile_functions

__all__ = ["export_run", "ExportResult", "FORMAT", "FORMAT_VERSION", "load_exported"]

FORMAT = "softpinn-export"
FORMAT_VERSION = 1
_UNITS = {"dx": "m", "dy": "m", "dL": "m", "theta": "rad", "phi": "rad"}


class ExportResult(dict):
    """What :func:`export_run` returns: the metadata written to ``model.json`` (a dict), plus
    ``functions`` (the exported Functions, symbolic) on the attribute of that name."""

    functions: dict


def _run_info(run: Path) -> dict:
    if not run.is_dir():
        raise UserError(f"RUN {run}: not a softpinn run directory (no such directory)")
    path = run / "config.json"
    if not path.is_file():
        raise UserError(f"RUN {run}: not a softpinn run directory (no config.json)")
    try:
        info = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise UserError(f"RUN {run}: config.json cannot be read ({exc})") from None
    if not isinstance(info, dict) or info.get("format") is None or "model" not in info:
        raise UserError(f"RUN {run}: not a softpinn run directory (config.json has no model)")
    return info


def _select_members(run: Path, info: dict, member, mean: bool) -> list[int | None]:
    """Which seeds to load: one (``member`` or the best), or all of them (``mean``)."""
    if member is not None and mean:
        raise UserError("--member and --mean exclude each other; give one of them")
    if member is not None and (isinstance(member, bool) or not isinstance(member, int)):
        raise UserError(f"--member must be an integer seed, got {member!r}")
    seeds = info.get("seeds") if "members" in info else [info.get("seed")]
    if member is not None and member not in seeds:
        what = "ensemble" if "members" in info else "single-model run"
        raise UserError(f"--member {member}: run {run} has no member with that seed "
                        f"({what}, seeds {seeds})")
    if mean:
        return list(seeds) if "members" in info else [None]
    return [member] if "members" in info else [None]


def _check_out(out: Path, force: bool) -> None:
    """The refusals of :func:`_prepare_out`, before any work and without writing anything."""

    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise UserError(f"--out {out}: directory exists and is not empty; pass --force to "
                        "overwrite it")
    outputs.check_parent(out, "--out")


def _prepare_out(out: Path, force: bool) -> None:
    _check_out(out, force)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    for old in [*out.glob("*.casadi"), *(out / f"model.{e}" for e in ("c", "h", "so", "json"))]:
        if old.is_file():  # --force: no file of an earlier export is left behind
            old.unlink()


def _checksum(run_dirs: list[Path]) -> str:
    """SHA-256 over each loaded member's config.json and model.eqx (in load order)."""
    h = hashlib.sha256()
    for d in run_dirs:
        for name in ("config.json", "model.eqx"):
            h.update(f"{name}\0".encode())
            h.update((d / name).read_bytes())
    return h.hexdigest()


def _dataset_facts(info: dict, run: Path) -> tuple[dict | None, dict | None]:
    """From the run's dataset file, when it can still be found (one read): its ``meta`` block,
    and per coordinate the least and greatest q of the run's training trajectories (the
    configurations its model was fitted on; None without a split)."""
    path = (info.get("dataset") or {}).get("path")
    if not path:
        return None, None
    cand = next((c for c in (Path(path), run / path) if c.is_file()), None)
    if cand is None:
        return None, None
    try:
        with np.load(cand, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"].item()))
            q, traj = np.asarray(z["q"], float), np.asarray(z["traj"])
    except (OSError, KeyError, ValueError):
        return None, None
    train = (info.get("split") or {}).get("train")
    q = q[np.isin(traj, np.asarray(train))] if train else q[:0]
    if q.ndim != 2 or not len(q):
        return meta, None
    return meta, {"min": q.min(axis=0).tolist(), "max": q.max(axis=0).tolist(),
                  "trajectories": [int(t) for t in train]}


def _names(n: int, m: int, kind: str, state_kind: str, meta: dict | None) -> dict:
    coords = (meta or {}).get("coordinates")
    if not (isinstance(coords, list) and len(coords) == n):
        coords = [f"q{i + 1}" for i in range(n)]
    second = "p" if state_kind == "momentum" else "qd"
    units = {}
    for c in coords:
        base = c.rstrip("0123456789")
        units[c] = _UNITS.get(base)
    return {
        "coordinates": coords,
        "state": coords + [f"{second}_{c}" for c in coords],
        "inputs": [f"u{j + 1}" for j in range(m)],
        "units": {
            "time": "s",
            "coordinates": units,
            "velocities": {c: (f"{u}/s" if u else None) for c, u in units.items()},
            "inputs": "as in the training data",
            "note": "null: unit not known from the training data",
        },
    }


#: what an export's compile timeout advises (a network has no quadrature nodes to reduce)
TIMEOUT_ADVICE = ("raise the limit with --compile-timeout S, or export with --no-compile (the "
                  "Functions and model.c, no library: they run in CasADi's virtual machine, "
                  "control compiles its own solver from them)")


#: C larger than this (MB) compiles at -O0: for a 4-coordinate Lagrangian network (8.7 MB of C,
#: 2 loaded cores) gcc took 20 s at -O0 and 174 s at -O1, and its q̈ ran 5x slower (0.53 ms
#: against 0.10 ms); ``softpinn control`` never calls the library (it compiles its own solver)
LARGE_SOURCE_MB = 4.0
LARGE_SOURCE_FLAGS = ("-O0", "-fPIC", "-shared")


def check_timeout(value, flag: str = "--compile-timeout") -> float:
    """``value`` as a number of seconds > 0, else one line naming ``flag``."""
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        seconds = math.nan
    if isinstance(value, bool) or not (math.isfinite(seconds) and seconds > 0):
        raise UserError(f"{flag}: expected a number of seconds > 0, got {value!r}")
    return seconds


def _write_c(fns: dict, work: Path, compiler, *, compile: bool = True,
             timeout: float = DEFAULT_TIMEOUT, log=lambda text: None) -> tuple[dict, Path | None]:
    """model.c + model.h (CasADi code generator) in ``work`` and, with ``compile``, the library
    from the project's code cache: (the ``c`` block of model.json, the library's path or None).
    A compile past ``timeout`` is a one-line :class:`CompilerTimeout` advising the flags."""

    cg = ca.CodeGenerator("model.c", {"with_header": True, "casadi_real": "double"})
    for key in sorted(fns):
        cg.add(fns[key])
    cg.generate(str(work) + os.sep)
    built = None
    size = (work / "model.c").stat().st_size / 1e6
    if compile:
        large = size > LARGE_SOURCE_MB
        flags = LARGE_SOURCE_FLAGS if large else DEFAULT_FLAGS
        log(f"compiling {size:.1f} MB of C"
            + (" at -O0 (a large source: -O1 compiles about 9x slower, its library runs "
               "about 5x faster; compile model.c yourself for that)" if large else "")
            + f" (a minute or more for a large network, at most {timeout:g} s; the library "
              "is cached for the next export of the same model)")
        try:
            built = compile_functions(fns, compiler=compiler, timeout=timeout, flags=flags)
        except CompilerTimeout:  # the build folder it names is gone: say what it compiled
            raise CompilerTimeout(f"the C compiler ran past its timeout of {timeout:g} s on "
                                  f"the export's {size:.1f} MB of C", TIMEOUT_ADVICE,
                                  timeout=timeout) from None
    library = None
    if built is not None and built.compiled and built.library is not None:
        library = "model.so"
    return {
        "source": "model.c",
        "header": "model.h",
        "library": library,
        "cache_key": (built.key or None) if built else None,
        "from_cache": built.from_cache if built else False,
        "compiler": built.compiler if built else None,
        "flags": list(built.flags) if built else [],
        "symbols": sorted(f.name() for f in fns.values()),
        "calling": "CasADi generated-code API: <name>(arg, res, iw, w, mem) with work sizes from "
                   "<name>_work(&sz_arg, &sz_res, &sz_iw, &sz_w); see model.h",
        **({} if compile else {"note": "exported with --no-compile: no library; compile model.c "
                                       "yourself (gcc -O1 -fPIC -shared model.c -o model.so -lm)"}),
    }, (built.library if library else None)


def export_run(run_dir, out_dir, *, member: int | None = None, mean: bool = False,
               force: bool = False, compiler=None, log=None, compile: bool = True,
               compile_timeout: float = DEFAULT_TIMEOUT) -> ExportResult:
    """Export a trained run (one member, the best member, or the ensemble mean) to ``out_dir``.

    ``member``: the seed of an ensemble member (default: the best member, as ``load_run``);
    ``mean``: the mean of all members' vector fields. ``force`` overwrites a non-empty
    ``out_dir``. ``compiler``: the C compiler (default: ``$CC``, gcc, cc). Returns the metadata
    written to ``model.json`` (with the symbolic Functions on ``.functions``). ``log(text)``:
    told each stage as it starts (the C compile of a large network takes a minute or more).
    ``compile``: build model.so (False: the Functions, model.c and model.h only);
    ``compile_timeout``: the compiler's limit in seconds (past it: one line, nothing written).
    """

    log = log or (lambda text: None)
    compile_timeout = check_timeout(compile_timeout)

    run, out = Path(run_dir), Path(out_dir)
    info = _run_info(run)
    seeds = _select_members(run, info, member, mean)
    _check_out(out, force)
    loaded = [load_run(run, member=s) for s in seeds]
    train_cfg = loaded[0].train_config
    params = [model_params(r.model) for r in loaded]
    log(f"building the CasADi Functions of {len(loaded)} model(s)")
    fns = export_functions(params, substeps=train_cfg.substeps, input_hold=train_cfg.input_hold)
    act = run_actuator(getattr(train_cfg, "actuator", "auto"), params[0]["m"])
    fns.update(actuator_functions(act, params[0]["m"]))
    with tempfile.TemporaryDirectory(prefix="softpinn-export-") as work:
        # the C is generated and compiled before --out is touched: a timeout leaves it as it was
        c_info, library = _write_c(fns, Path(work), compiler, compile=compile,
                                   timeout=compile_timeout, log=log)
        _prepare_out(out, force)
        log(f"writing the Functions and model.c to {out}")
        fns["qdd"].save(str(out / "model.casadi"))
        for key, fn in fns.items():
            fn.save(str(out / f"{key}.casadi"))
        for name in ("model.c", "model.h"):
            shutil.copyfile(Path(work) / name, out / name)
        if library is not None:
            shutil.copyfile(library, out / "model.so")

    first = params[0]
    n, m = first["n"], first["m"]
    top = loaded[0].info
    meta, q_range = _dataset_facts(top, run)
    result = ExportResult({
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "softpinn": __version__,
        "casadi": ca.__version__,
        "kind": first["kind"],
        "state_kind": first["state_kind"],
        "n": n,
        "m": m,
        "dtype_trained": loaded[0].model_config.dtype,
        **_names(n, m, first["kind"], first["state_kind"], meta),
        "ensemble": {
            "mode": "mean" if mean and len(loaded) > 1 else "member",
            "seeds": [r.seed for r in loaded],
            "all_seeds": info.get("seeds", [info.get("seed")]),
        },
        "step": {"method": "rk4", "substeps": train_cfg.substeps,
                 "input_hold": train_cfg.input_hold},
        "actuator": actuator_metadata(act, m),
        "run": {
            "path": str(run.absolute()),
            "members": [str(r.run_dir.absolute()) for r in loaded],
            "sha256": _checksum([r.run_dir for r in loaded]),
        },
        "training": {
            "dataset": top.get("dataset"),
            "data_spec": (meta or {}).get("spec", {}).get("name") if meta else None,
            "split": top.get("split"),
            "q_range": q_range,
            "pairs": top.get("pairs"),
            "model": top.get("model"),
            "train": top.get("train"),
        },
        "functions": {
            key: {"name": fn.name(), "inputs": list(fn.name_in()),
                  "outputs": list(fn.name_out()), "file": f"{key}.casadi"}
            for key, fn in fns.items()
        },
        "model_file": {"file": "model.casadi", "function": "qdd"},
        "c": c_info,
    })
    # issue 44: every loader checks these before CasADi sees a file (:mod:`.verify`)
    written = ["model.casadi", *(f"{key}.casadi" for key in fns),
               *(c_info[k] for k in ("source", "header", "library") if c_info.get(k))]
    result[CHECKSUMS] = file_checksums(out, written)
    tmp = out / ".model.json.tmp"
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, out / "model.json")
    if not act.is_identity:
        log(f"actuator: {result['actuator']['note']}")
    result.functions = fns
    return result


def load_exported(out_dir) -> dict[str, ca.Function]:
    """The Functions of an export directory, by name (``casadi.Function.load`` of each file),
    after checking every file's sha256 against ``model.json`` (:func:`.verify.read_export`: a
    changed or missing file is refused in one line; an export written before the checksums
    loads unverified)."""
    out = Path(out_dir)
    meta, verified = read_export(out)
    try:
        files = {k: str(v["file"]) for k, v in meta["functions"].items()}
    except (TypeError, KeyError, AttributeError):
        raise UserError(f"{out / 'model.json'}: its functions table is damaged; export the "
                        "run again") from None
    unlisted = [f for f in files.values() if verified and f not in meta[CHECKSUMS]]
    if unlisted:  # every file CasADi loads has been checked
        raise UserError(f"{out / unlisted[0]}: model.json lists no checksum for it; export "
                        "the run again")
    return {k: ca.Function.load(str(out / f)) for k, f in files.items()}
