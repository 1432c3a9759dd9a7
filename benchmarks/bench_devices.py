"""Data-parallel training over devices (issue 21): samples/s of `train` with --devices 1, 2, 4,
and whether the parameters agree with the one-device run; prints one JSON object.

On a CPU the devices are simulated (XLA_FLAGS=--xla_force_host_platform_device_count=4, set by
this script before JAX starts): they share the machine's cores, so this measures correctness
and overhead, not speed-up. On a machine with several GPUs it measures the speed-up.

Usage: python benchmarks/bench_devices.py [--epochs 20] [--trajectories 40] [--batch 256]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=4")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from datagen import make_dataset  # noqa: E402

from softpinn.learn._config import TrainConfig  # noqa: E402
from softpinn.learn._models import ModelConfig  # noqa: E402
from softpinn.learn._train import load_run, train  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--trajectories", type=int, default=40)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--width", type=int, default=64)
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp())
    data = make_dataset(folder / "msd.npz", trajectories=args.trajectories, duration=10.0)
    model = ModelConfig(kind="lagrangian", n=2, m=1, mass=(args.width, 3),
                        potential=(args.width, 3), damping=(16, 2), input=(16, 2))
    rows, leaves = [], {}
    counts = [d for d in (1, 2, 4) if d <= jax.device_count()]
    for d in counts:
        cfg = TrainConfig(model=model, epochs=args.epochs, batch_size=args.batch, devices=d)
        train(data, TrainConfig(model=model, epochs=1, batch_size=args.batch, devices=d),
              folder / f"warm{d}")  # compile once, so the timed run measures training
        t0 = time.perf_counter()
        res = train(data, cfg, folder / f"run{d}")
        seconds = time.perf_counter() - t0
        pairs = res.metrics["pairs"]["train"]
        run = load_run(folder / f"run{d}")
        leaves[d] = np.concatenate([np.ravel(x) for x in
                                    jax.tree.leaves(eqx.filter(run.model, eqx.is_array))])
        rows.append({"devices": d, "seconds": seconds,
                     "samples_per_s": args.epochs * (pairs // args.batch) * args.batch / seconds,
                     "max_param_difference_vs_1": float(np.max(np.abs(leaves[d] - leaves[1])))})
    print(json.dumps({
        "benchmark": "bench_devices", "backend": jax.default_backend(),
        "devices_available": jax.device_count(), "device_kind": jax.devices()[0].device_kind,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}",
        "settings": vars(args), "results": rows,
    }, indent=1))


if __name__ == "__main__":
    main()
