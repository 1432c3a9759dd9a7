"""``softpinn simulate MODEL --out FILE.npz``: simulate trajectories of a model into a dataset
file; run in :mod:`bridge.cli._simulate_run`."""

from __future__ import annotations

SIGNALS = ("zero", "sinusoid", "multisine", "step", "chirp")


def add_parser(subparsers):
    p = subparsers.add_parser(
        "simulate",
        help="simulate trajectories of a model into a dataset file (.npz)",
        description="Simulate trajectories (compiled equations of motion, cvodes or fixed-step "
        "RK4) and write a dataset file. Every setting not given comes from the spec's [data] "
        "table (a preset's: the paper's settings), or, for a spec without one, from defaults "
        "worked out from its physics (printed when used).",
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL",
                   help="preset name (see 'softpinn models') or spec file")
    p.add_argument("--out", required=True, metavar="FILE.npz", help="dataset file to write")
    p.add_argument("--trajectories", type=int, metavar="K",
                   help="number of trajectories (default: [data]'s train and test counts)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="seconds per trajectory (default: [data] duration)")
    p.add_argument(
        "--settle",
        type=float,
        metavar="S",
        help="seconds simulated before recording starts (default: [data] settle)",
    )
    p.add_argument("--rate", type=float, metavar="HZ",
                   help="output rate [Hz] (default: [data] rate)")
    p.add_argument(
        "--dt", type=float, metavar="S", help="fixed RK4 step [s] (implies --integrator rk4)"
    )
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="farm the trajectories out to Ray: a local instance (no ADDRESS), "
                   "'auto' or HOST:PORT of a cluster (needs softpinn[ray]; the data set is the "
                   "same as without)")
    p.add_argument("--integrator", choices=("cvodes", "rk4", "jax-rk4"),
                   help="cvodes (adaptive, CasADi), rk4 (fixed step, CasADi) or jax-rk4 (fixed "
                   "step, every trajectory at once: batched C kernels of the exact model on "
                   "the CPU, its JAX translation on a GPU or with --no-compile; default: the "
                   "spec's)")
    p.add_argument("--signal", choices=SIGNALS, help="input signal kind (ranges from [data])")
    p.add_argument("--seed", type=int, metavar="S", help="random seed (default: [data] seed)")
    p.add_argument(
        "--noise",
        type=float,
        metavar="SIGMA",
        help="standard deviation of Gaussian measurement noise (default: [data] noise, "
        "else 0)",
    )
    p.add_argument("--equilibria", type=int, default=0, metavar="K",
                   help="also store K stable static equilibria G(q*) = A(q*) u* under constant "
                   "inputs drawn in the signals' input box (eq_q, eq_u, eq_force; labels for "
                   "train --equilibrium-weight; default 0: none)")
    p.add_argument("--rtol", type=float,
                   help="cvodes relative tolerance (default: [data] rtol, else 1e-10)")
    p.add_argument("--atol", type=float,
                   help="cvodes absolute tolerance (default: [data] atol, else 1e-10)")
    p.add_argument(
        "--threads",
        type=int,
        default=2,
        metavar="N",
        help="trajectories integrated at once (default 2)",
    )
    p.add_argument(
        "--no-compile",
        action="store_true",
        help="run the equations in CasADi's virtual machine, no C compiler",
    )
    p.add_argument(
        "--cache",
        metavar="DIR",
        help="compiled-code cache (default $SOFTPINN_CACHE or ~/.cache/softpinn)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from softpinn.bridge.cli import _simulate_run  # deferred: casadi (and jax) at start-up

    return _simulate_run.run(args)
