"""``softpinn simulate MODEL --out FILE.npz``: a data set (:func:`softpinn.symbolic.make_dataset`)
with the preset's ``[data]`` settings unless flags say otherwise (its parser:
:mod:`bridge.cli.simulate`; checks shared with ``derive`` in :mod:`bridge.cli.checks`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from softpinn.bridge.base import outputs
from softpinn.bridge.cli.bars import CountBar
from softpinn.bridge.cli.checks import check_writable, positive, warnings_as_lines
from softpinn.errors import UserError
from softpinn.symbolic import (
    attach,
    check_seed,
    count_of,
    data_config,
    equilibria,
    load_spec,
    make_dataset,
    plan_dataset,
    ray_simulator,
    resample,
    write_datasets,
)


def _test_words(data) -> str:
    """'; trajectories 8, 9 for test' (the split train holds out by default), or ''."""
    test = (data.meta.get("splits") or {}).get("test") or []
    if not test:
        return ""
    ids = ", ".join(map(str, test))
    return f"; trajector{'y' if len(test) == 1 else 'ies'} {ids} for test"


def run(args) -> int:
    spec = load_spec(args.model)
    cfg = data_config(spec)
    out = Path(args.out)
    if out.suffix != ".npz":
        raise UserError(f"--out {out}: a dataset file must end in .npz")
    for field in ("duration", "rate", "dt", "rtol", "atol"):
        if getattr(args, field) is not None:
            positive(field, getattr(args, field))
    if args.trajectories is not None and args.trajectories < 1:
        raise UserError(f"--trajectories: must be at least 1, got {args.trajectories}")
    if args.noise is not None and not (np.isfinite(args.noise) and args.noise >= 0):
        raise UserError(f"--noise: must be a non-negative standard deviation, got {args.noise}")
    if args.settle is not None and not (np.isfinite(args.settle) and args.settle >= 0):
        raise UserError(f"--settle: must be a non-negative number of seconds, got {args.settle}")
    if args.threads < 1:
        raise UserError(f"--threads: must be at least 1, got {args.threads}")
    if args.equilibria < 0:
        raise UserError(f"--equilibria: must be a count >= 0, got {args.equilibria}")
    if args.seed is not None:
        check_seed(args.seed)
    use_jax = args.integrator == "jax-rk4"
    integrator = "rk4" if use_jax else (
        args.integrator or ("rk4" if args.dt is not None else cfg.integrator))
    if args.dt is not None and integrator != "rk4":
        raise UserError("--dt: is the fixed step of --integrator rk4; cvodes takes --rate")
    # the paper's resampled rates (task 5): the file at the highest, siblings at the others
    extra_rates: list[float] = []
    if integrator == "cvodes" and args.rate is None and len(cfg.rates) > 1:
        extra_rates = sorted(r for r in cfg.rates if r != cfg.rate)
    targets = [out] + [_sibling(out, r) for r in extra_rates]
    for path in targets:
        if path.is_dir():
            raise UserError(f"--out {path}: is a folder, not a dataset file")
        if path.exists() and not args.force:
            raise UserError(f"--out {path}: file exists (use --force to overwrite)")
    check_writable("--out", out)
    for path in targets:  # one writer of each file at a time (softpinn.locks)
        outputs.hold(path, "simulate")

    plan = plan_dataset(
        spec,
        trajectories=args.trajectories,
        duration=args.duration,
        settle=args.settle,
        rate=args.rate,
        dt=args.dt,
        integrator=integrator,
        signal=args.signal,
        seed=args.seed,
        noise=args.noise,
        rtol=args.rtol,
        atol=args.atol,
        threads=args.threads,
    )
    bar = None if args.quiet else CountBar(plan.trajectories, f"simulate {spec.name}", "traj")
    failed = True
    try:
        t0 = time.perf_counter()
        with warnings_as_lines():
            if args.ray is not None and use_jax:
                raise UserError("--ray: farms out the CasADi integrators; --integrator jax-rk4 "
                                "runs every trajectory at once already")
            if args.ray is not None:
                sim = ray_simulator(spec, address=args.ray, compile=not args.no_compile,
                                    cache=args.cache, num_cpus=args.threads
                                    if args.ray == "local" and args.threads > 1 else None)
                data = make_dataset(plan=plan, simulator=sim,
                                    progress=bar,
                                    simulator_meta={"compiled": not args.no_compile,
                                                    "farmed_out": f"ray ({args.ray})"})
            elif use_jax:
                # deferred: jax, for this integrator alone
                from softpinn.bridge.cli._jax import enable_x64
                from softpinn.bridge.exact import make_dataset as jax_dataset  # deferred: jax

                enable_x64()
                data = jax_dataset(plan=plan, progress=bar,
                                   backend="jax" if args.no_compile else "auto")
            else:
                data = make_dataset(
                    plan=plan,
                    compile=not args.no_compile,
                    cache=args.cache,
                    progress=bar,
                )
        seconds = time.perf_counter() - t0
        failed = False
    finally:
        if bar is not None:
            bar.close(failed=failed)  # an error leaves one clean line on stderr
    if args.equilibria:
        data = attach(data, equilibria(spec, args.equilibria, seed=plan.seed))
    subs = [resample(data, rate) for rate in extra_rates]
    # every file complete before any appears: an interrupt leaves none, so a rerun is not refused
    write_datasets([(out, data), *zip(targets[1:], subs, strict=True)], force=args.force)
    k, per = data.meta["trajectories"], data.meta["samples_per_trajectory"]
    print(
        f"{spec.name}: wrote {out} ({count_of(k, 'trajectory', 'trajectories')} x "
        f"{count_of(per, 'sample')} at "
        f"{data.meta['rate']:g} Hz, {data.meta['simulation']['integrator']}"
        f"{_batch_word(data) if use_jax else ''}{_test_words(data)}) in {seconds:.2f} s"
    )
    if args.equilibria:
        info = data.meta["equilibria"]
        print(f"{spec.name}: {args.equilibria} stable equilibria (largest residual "
              f"{info['max_residual']:.1e}, {info['draws']} inputs drawn)")
    for rate, path, sub in zip(extra_rates, targets[1:], subs, strict=True):
        print(
            f"{spec.name}: wrote {path} (resampled at {rate:g} Hz, "
            f"{sub.meta['samples_per_trajectory']} samples per trajectory)"
        )
    return 0


def _batch_word(data) -> str:
    """How --integrator jax-rk4 ran: in JAX or in the batched C kernels."""
    return " in JAX" if data.meta.get("compiled") == "jax" else " in batched C kernels"


def _sibling(path: Path, rate: float) -> Path:
    return path.with_name(f"{path.stem}_{rate:g}hz{path.suffix}")

