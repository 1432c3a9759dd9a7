"""``softpinn control MODEL --out DIR``: model-predictive control of a model's tip with learned
models, the true model as plant; run in :mod:`bridge.cli._control_run`. The controller's flags
take their defaults from :class:`softpinn.bridge.control.MPCConfig`, so they are added when the
command is parsed."""

from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        "control",
        help="model-predictive control of a model's tip with learned models (true model as "
             "plant)",
        description=(
            "Steer the true model MODEL (cvodes) along references (a circle, steps) with "
            "nonlinear MPC, once per prediction model: the true model itself (the best case), "
            "each learned run in --runs (exported to CasADi in-process, as `softpinn export`) "
            "and the true model linearised at the centre. Writes results.json (tip tracking "
            "error, input effort, solver failures, solve time per step), report.md, figures/ "
            "and traces/ into --out."
        ),
    )
    p.set_defaults(func=run)
    return p


def add_arguments(p) -> None:
    # deferred: casadi at start-up (the defaults are MPCConfig's)
    from softpinn.bridge.control import (
        LARGE_ARM_N,
        QP_SOLVERS,
        REFERENCES,
        SENSITIVITIES,
        SOLVERS,
        MPCConfig,
    )

    d = MPCConfig()
    p.add_argument("model", metavar="MODEL",
                   help="the plant: a preset name (see 'softpinn models') or spec file")
    p.add_argument("--runs", nargs="+", default=[], metavar="RUN",
                   help="trained runs (`softpinn train` folders, `softpinn reproduce` stage "
                        "folders holding run/) or `softpinn export` folders (default: none)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--member", type=int, default=None, metavar="K",
                       help="use the ensemble member with seed K of each run (default: the "
                            "best member)")
    which.add_argument("--mean", action="store_true",
                       help="use the mean of each ensemble's members")
    p.add_argument("--no-true", action="store_true",
                   help="leave out the controller with the true model")
    p.add_argument("--no-linear", action="store_true",
                   help="leave out the controller with the linearised true model")

    r = p.add_argument_group("references")
    r.add_argument("--reference", nargs="+", choices=REFERENCES, default=list(REFERENCES),
                   help="references to follow")
    r.add_argument("--duration", type=float, default=None, metavar="S",
                   help="seconds per reference (default: one period of the circle, each step "
                        "target held --hold)")
    r.add_argument("--center", type=float, nargs="+", default=None, metavar="Q",
                   help="the centre in q (n values; default: the middle of the spec's [data] "
                        "initial coordinates)")
    r.add_argument("--radius", type=float, default=None, metavar="R",
                   help="radius of the circle and size of the steps, in q's first two "
                        "coordinates (default: 15%% of their [data] range)")
    r.add_argument("--period", type=float, default=4.0, metavar="S",
                   help="seconds per round of the circle")
    r.add_argument("--hold", type=float, default=1.0, metavar="S",
                   help="seconds each step target is held")

    m = p.add_argument_group("controller")
    m.add_argument("--rate", type=float, default=1.0 / d.dt, metavar="HZ",
                   help="control rate (the MPC step is 1 / rate)")
    m.add_argument("--horizon", type=int, default=None, metavar="N",
                   help=f"prediction horizon in control steps (default: {d.horizon}; 10 for "
                        f"arms of {LARGE_ARM_N} coordinates or more)")
    m.add_argument("--substeps", type=int, default=d.substeps, metavar="K",
                   help="least RK4 sub-steps per control step in the prediction (more for a "
                        "model that is stiff at the centre)")
    m.add_argument("--stiffness", type=float, default=d.stiffness, metavar="HR",
                   help="raise the sub-steps until h max|lambda| <= HR for the eigenvalues "
                        "lambda of the model's Jacobian at the centre (RK4 is stable up to "
                        "about 2.8; 0: never raise them)")
    m.add_argument("--weight-y", dest="weight_y", type=float, default=d.weight_y, metavar="W",
                   help="weight of the squared output error (per unit of the output squared)")
    m.add_argument("--weight-u", dest="weight_u", type=float, default=d.weight_u, metavar="W",
                   help="weight of the squared input")
    m.add_argument("--weight-du", dest="weight_du", type=float, default=d.weight_du,
                   metavar="W", help="weight of the squared input change per step")
    m.add_argument("--u-min", dest="u_min", type=float, nargs="+", default=None, metavar="U",
                   help="lower input bounds (m values or one; default: the range of the inputs "
                        "`simulate` draws for the spec, widened by a quarter; -inf lifts it)")
    m.add_argument("--u-max", dest="u_max", type=float, nargs="+", default=None, metavar="U",
                   help="upper input bounds (as --u-min)")
    m.add_argument("--solver", choices=SOLVERS, default=d.solver,
                   help="sqp: Gauss-Newton SQP from generated C; ipopt: IPOPT, exact Hessian")
    m.add_argument("--qpsol", choices=QP_SOLVERS, default=d.qpsol,
                   help="the SQP's QP solver (used when an input bound is active)")
    m.add_argument("--max-iter", dest="max_iter", type=int, default=None, metavar="N",
                   help="solver iterations per control step (default: 1 for sqp, the real-time "
                        "iteration; 50 for ipopt)")
    m.add_argument("--offset-free", dest="offset_free", type=float, default=d.offset_free,
                   metavar="GAIN",
                   help="offset-free MPC: estimate a constant state disturbance from each "
                        "step's prediction error with this gain in [0, 1] and predict with it "
                        "(removes a learned model's steady offset; 0: off; 0.2-0.3 worked "
                        "best on task 4)")
    m.add_argument("--offset-free-rate", dest="offset_free_rate", type=float,
                   default=d.offset_free_rate, metavar="BETA",
                   help="with --offset-free: estimate how the disturbance changes per step "
                        "too (an alpha-beta filter with this second gain in [0, 1]), so that "
                        "a learned model's error drifting along a moving reference is not "
                        "lagged (about GAIN^2 / (2 - GAIN) damps it critically; 0: off)")
    m.add_argument("--sensitivities", choices=SENSITIVITIES, default=None,
                   help=f"(default: {d.sensitivities}; lifted for arms of {LARGE_ARM_N} "
                        "coordinates or more) the SQP's sensitivities: exact (RK4's "
                        "variational equations, four "
                        "Jacobians of the model per sub-step); frozen (one Jacobian per "
                        "control step; the prediction stays exact, a network's solve is "
                        "several times faster); lifted (frozen, and each step linearised "
                        "about the last plan's predicted states: one rollout per solve)")
    m.add_argument("--no-codegen", action="store_true",
                   help="compile nothing: the solver's functions run in CasADi's virtual "
                        "machine, and a run's export gets no model.so (the prediction uses "
                        "its Functions, not the library)")
    m.add_argument("--compile-timeout", dest="compile_timeout", type=float,
                   default=d.compile_timeout, metavar="S",
                   help="seconds the C compiler may take per library (the solver's, a run's "
                        "export)")
    m.add_argument("--compiler", metavar="CC", help="C compiler (default $CC, gcc, cc)")

    p.add_argument("--force", action="store_true",
                   help="write into a non-empty folder that is not an earlier control output "
                        "(nothing in it is removed)")
    p.add_argument("--json", action="store_true", help="print results.json")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run(args) -> int:
    from softpinn.bridge.cli import _control_run  # deferred: casadi (and jax) at start-up

    return _control_run.run(args)
