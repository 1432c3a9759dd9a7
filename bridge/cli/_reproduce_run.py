"""``softpinn reproduce``: a study end to end (:func:`softpinn.bridge.app.reproduce`), with a bar
per trained model (:class:`bridge.cli.bars.EpochBar`); its parser: :mod:`bridge.cli.reproduce`."""

from __future__ import annotations

from softpinn.bridge.app import reproduce
from softpinn.bridge.cli.bars import EpochBar
from softpinn.bridge.tasks import ReproduceConfig
from softpinn.learn.xlaflags import use_fast_compile


def run(args) -> int:
    if args.quick:  # compiling is most of a quick run: XLA's fast-compile settings
        use_fast_compile()
    config = ReproduceConfig(
        task=args.task, quick=args.quick, seeds=args.seeds, epochs=args.epochs,
        lbfgs_steps=args.lbfgs_steps, float32=args.float32, jobs=args.jobs,
        actuator=args.actuator, prior=args.prior,
    )
    bar = None if args.quiet else EpochBar()

    def log(line: str) -> None:
        if bar is not None:
            bar.write(line)
    try:
        result = reproduce(config, args.out, log=log, progress=bar, force=args.force)
    finally:
        if bar is not None:
            bar.close()
    print(f"wrote {result.report} ({result.seconds:.0f} s)")
    return 0
