"""``softpinn train``: flags mapped onto :func:`learn._train.train`; the progress bar is drawn
from the training callback (``softpinn predict``: :mod:`bridge.cli.predict`)."""

from __future__ import annotations

import json
import sys

from softpinn.bridge.cli.bars import LbfgsBar as LbfgsBar  # re-exported: cli.bridge draws it
from softpinn.bridge.cli.bars import TrainBar
from softpinn.bridge.cli.runnotes import held_out_text
from softpinn.errors import UserError
from softpinn.learn import (
    GROUPS,
    RESUMABLE,
    ModelConfig,
    TrainConfig,
    check_run_dir,
    data_force_weights,
    load_dataset,
    load_run,
    mass_scale,
    read_json,
    resolve_devices,
    split_trajectories,
    train,
)
from softpinn.learn.distributed import initialize, is_writer

_Bar = TrainBar  # the name the tests and older code use

MODEL_KINDS = ("lagrangian", "hamiltonian", "blackbox", "lagrangian-hessian")
NETS = ("mass", "potential", "damping", "input", "hidden")
#: Train settings whose flags are not generated one to one from their field.
_CUSTOM = ("test_trajectories",)


def _model_defaults() -> dict:
    import dataclasses


    return {f.name: f.default for f in dataclasses.fields(ModelConfig)}


def _devices(text: str) -> int:
    """--devices N, or all (0, as the setting's help says)."""
    import argparse

    if text == "all":
        return 0
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a count or 'all', got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a count >= 1, or 'all' (or 0), got {value}")
    return value


def _split_flags(group) -> None:
    group.add_argument("--test-trajectories", type=int, nargs="+", default=None, metavar="ID",
                       help="trajectory ids held out for testing (default: the test split the data "
                       "file records, from simulate's spec or import --test-trajectories; "
                       "else 20%% drawn at random)")
    group.add_argument("--test-count", type=int, default=None, metavar="K",
                       help="hold out K trajectories drawn at random")


def add_setting_flags(parser, *, skip=_CUSTOM, title=str, split_flags=_split_flags) -> None:
    """One flag per :class:`learn._config.TrainConfig` setting, in argument groups (budget,
    optimizer, loss, split, ensemble, devices), with the field's default, help and choices: the
    defaults live in the config alone. ``skip``: settings whose flags the caller spells itself;
    ``title(group)``: the groups' titles; ``split_flags(group)`` adds the flags of the split
    group that are not one field each (``softpinn sweep`` uses all three)."""
    import types
    import typing


    hints = typing.get_type_hints(TrainConfig)
    for group in GROUPS:
        g = parser.add_argument_group(title(group))
        for f in TrainConfig.settings(group):
            if f.name in skip:
                continue
            hint = hints[f.name]
            if isinstance(hint, types.UnionType):
                hint = next(a for a in typing.get_args(hint) if a is not type(None))
            kw = {"default": f.default, "help": f.metadata["help"].replace("%", "%%")}
            if f.name == "devices":
                kw.update(type=_devices, metavar="N|all")
            elif typing.get_origin(hint) is tuple:  # accel_weights: n numbers
                kw.update(type=float, nargs="+", metavar="W")
            elif f.metadata.get("choices"):
                kw["choices"] = f.metadata["choices"]
            else:
                kw["type"] = hint
                kw["metavar"] = "N" if hint is int else ("RUN" if f.name == "init" else "X")
            g.add_argument(f"--{f.name.replace('_', '-')}", **kw)
        if group == "split":
            split_flags(g)


def add_network_flags(parser, title: str = "network") -> None:
    """The flags of the network (:class:`learn._model_config.ModelConfig`), defaults from its
    fields."""
    net = parser.add_argument_group(title)
    net.add_argument("--width", type=int, default=None, help="width of every sub-network")
    net.add_argument("--depth", type=int, default=None,
                     help="hidden layers of every sub-network")
    for name in NETS:
        net.add_argument(f"--{name}", type=int, nargs=2, metavar=("W", "D"), default=None,
                         help=f"width and depth of the {name} network (default: the kind's)")
    model_defaults = _model_defaults()
    net.add_argument("--activation", default=model_defaults["activation"],
                     help="activation of every sub-network (softplus, tanh, ...)")
    net.add_argument("--damping-form", choices=("network", "constant", "none"),
                     default=model_defaults["damping_form"],
                     help="D(q): a network, a learned constant, or none")
    net.add_argument("--input-form", choices=("network", "constant"),
                     default=model_defaults["input_form"],
                     help="A(q): a network or a learned constant")
    net.add_argument(
        "--known-input", default=None, metavar="MODEL|FILE",
        help="fix A(q), not learned (physics models): the exact A(q) of a symbolic model (a "
        "preset name such as task4, or a spec .toml), a constant n x m matrix (FILE.npy, or "
        "FILE.json holding a list of rows), or A(q) as a program (A.program.json of 'softpinn "
        "derive --programs', for a machine without CasADi)",
    )
    net.add_argument("--eps", type=float, default=model_defaults["eps"],
                     help="Cholesky diagonal shift of M")
    net.add_argument(
        "--mass-init", default=None, metavar="X|data",
        help="initial diagonal of M (Lagrangian) or M^-1 (Hamiltonian); 'data': from the "
        "data's rms(p)/rms(qd) per coordinate (use it when masses are far from 1 and the data fix "
        "their scale: momenta trained on, or --known-input; with A learned, M's scale is free "
        "and moving it alone makes the first accelerations that many times off)",
    )
    net.add_argument("--state", choices=("velocity", "momentum"), default=None,
                     help="state of a black-box model (default velocity)")
    net.add_argument("--float32", action="store_true", help="train in float32 (default float64)")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "train",
        help="train a physics-inspired (or black-box) model on a dataset file",
        description=(
            "Train Lagrangian (eq. 6), Hamiltonian (eq. 7) or black-box networks with the "
            "one-step Runge-Kutta loss (eqs. 8/9) or the acceleration loss (eq. 10), AdamW. "
            "Writes RUN/config.json, model.eqx, checkpoint.eqx, history.csv, metrics.json, "
            "loss.png (one seed-<s>/ folder per member of an ensemble)."
        ),
    )
    p.add_argument("data", metavar="DATA.npz", help="dataset file")
    p.add_argument("--model", choices=MODEL_KINDS, default=None, help="network kind (required)")
    p.add_argument("--out", required=True, metavar="RUN", help="run directory to write")
    add_setting_flags(p)
    p.add_argument("--accel-weights-from", default=None, metavar="RUN",
                   help="set --accel-weights from RUN's trained model: mean(s) / s_i, s_i the "
                   "rms of its inertial force M̂ q̈ over the training data (a second pass in "
                   "force space that weighs each coordinate by its own force scale)")
    add_network_flags(p)
    hosts = p.add_argument_group("several processes (hosts)")
    hosts.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                       help="address of process 0 when training on several processes (with "
                       "--num-processes and --process-id; then --devices all)")
    hosts.add_argument("--num-processes", type=int, default=None, metavar="P",
                       help="how many processes train together")
    hosts.add_argument("--process-id", type=int, default=None, metavar="I",
                       help="this process's index, 0 .. P-1 (process 0 writes the run)")
    hosts.add_argument("--cluster", action="store_true",
                       help="take the processes from the cluster's environment (SLURM, Open MPI)")

    run = p.add_argument_group("run directory")
    run.add_argument(
        "--resume", action="store_true",
        help="continue the run in --out with its stored options; of the options given again, "
        + ", ".join(f"--{n.replace('_', '-')}" for n in RESUMABLE)
        + " may change, any other change is refused",
    )
    run.add_argument("--force", action="store_true",
                     help="overwrite an existing run directory (removes only softpinn's files)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    p.set_defaults(func=cmd_train, given=frozenset())
    track_given(p)


def track_given(parser) -> None:
    """Record in ``args.given`` the destination of every option typed on the command line
    (``--resume`` applies those, and only those, to the stored settings)."""
    for action in parser._actions:
        if not action.option_strings or action.dest == "help":
            continue
        cls = type(action)

        def __call__(self, parser, namespace, values, option_string=None, _cls=cls):
            namespace.given = frozenset(namespace.given) | {self.dest}
            _cls.__call__(self, parser, namespace, values, option_string)

        action.__class__ = type(f"Tracked{cls.__name__}", (cls,), {"__call__": __call__})


def _enable_x64():
    import jax

    jax.config.update("jax_enable_x64", True)


def _model_config(args, n: int, m: int, data=None, train_ids=None):
    """The network's configuration from the flags; ``train_ids``: the training trajectories
    ``--mass-init data`` reads (None: all of the file's)."""

    if args.model is None:
        raise UserError(f"--model is required: one of {', '.join(MODEL_KINDS)}")
    physics_nets = [net for net in NETS if net != "hidden" and getattr(args, net) is not None]
    if args.model == "blackbox" and physics_nets:
        raise UserError(f"--{physics_nets[0]} sizes a physics model's network; a black box's "
                        "is --hidden W D")
    if args.model != "blackbox" and getattr(args, "hidden", None) is not None:
        raise UserError(f"--hidden sizes the black box's network; a {args.model} network has "
                        "--mass, --potential, --damping and --input")
    kw = {}
    defaults = ModelConfig(kind=args.model, n=n, m=m)
    for net in NETS:
        w, d = getattr(defaults, net)
        if args.width is not None:
            w = args.width
        if args.depth is not None:
            d = args.depth
        if getattr(args, net) is not None:
            w, d = getattr(args, net)
        kw[net] = (w, d)
    if args.state is not None:
        kw["state_kind"] = args.state
    if args.mass_init is not None:
        if args.model == "blackbox":
            raise UserError("--mass-init applies to physics models, not --model blackbox")
        if args.mass_init == "data":
            kw["mass_init"] = mass_scale(data, args.model, train_ids)
        else:
            try:
                kw["mass_init"] = float(args.mass_init)
            except ValueError:
                raise UserError(
                    f"--mass-init: expected a number or 'data', got {args.mass_init!r}"
                ) from None
    input_form = args.input_form
    if getattr(args, "known_input", None) is not None:
        if args.model == "blackbox":
            raise UserError("--known-input applies to physics models, not --model blackbox")
        if "input_form" in getattr(args, "given", ()) and args.input_form != "known":
            raise UserError(f"--known-input fixes A(q): leave out --input-form "
                            f"{args.input_form}")
        from softpinn.bridge.cli.known import known_input

        kw["known_input"] = known_input(args.known_input, n, m)
        input_form = "known"
    return ModelConfig(
        kind=args.model,
        n=n,
        m=m,
        activation=args.activation,
        damping_form=args.damping_form,
        input_form=input_form,
        eps=args.eps,
        dtype="float32" if args.float32 else "float64",
        **kw,
    )


def cmd_train(args) -> int:
    _enable_x64()

    initialize(args.coordinator, args.num_processes, args.process_id, cluster=args.cluster)
    if not is_writer():
        args.quiet = True  # one progress bar: process 0's

    if args.resume and args.force:
        raise UserError("--resume and --force exclude each other")

    check_run_dir(args.out, force=args.force, resume=args.resume)  # before any work or bar
    if args.test_trajectories is not None and args.test_count is not None:
        raise UserError("give --test-trajectories or --test-count, not both")
    if args.resume:
        from pathlib import Path

        if args.accel_weights_from is not None:
            raise UserError("--accel-weights-from: give it when a run starts (the weights are "
                            "stored in the run's config.json), not with --resume")
        stored = read_json(Path(args.out) / "config.json")
        if not isinstance(stored, dict) or "train" not in stored:
            raise UserError(f"--resume: {Path(args.out) / 'config.json'} is not a softpinn run")
        config = TrainConfig.from_dict(stored["train"])
        data = load_dataset(args.data, n=config.model.n, m=config.model.m)
        config = _resumed_with_flags(args, config, data)
    else:

        data = load_dataset(args.data)
        test = args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
        # the training split as train() draws it: --mass-init data reads no test trajectory
        train_ids, _ = split_trajectories(data, test=test, seed=args.split_seed)
        mc = _model_config(args, data.n, data.m, data, train_ids)
        if args.accel_weights_from is not None:
            if args.accel_weights is not None:
                raise UserError("give --accel-weights or --accel-weights-from, not both")
            args.accel_weights = _weights_from(args.accel_weights_from, data, train_ids,
                                               args.accel_labels)
        config = TrainConfig(
            model=mc, test_trajectories=test,
            **{f.name: getattr(args, f.name) for f in TrainConfig.settings()
               if f.name not in _CUSTOM},
        )

    resolve_devices(config.devices)  # before the bar: a refusal is one line
    bar = _Bar(config.epochs * config.seeds, disable=args.quiet)
    bar.start()
    try:
        result = train(
            data,
            config,
            args.out,
            progress=bar,
            force=args.force,
            resume=args.resume,
            warn=_warn,
        )
    finally:
        bar.close()
    if not is_writer():
        return 0  # process 0 reports
    m = result.metrics
    if args.json:
        print(json.dumps({"run": str(result.run_dir), **_nulls(m)}, allow_nan=False))
    else:
        bt = m["best_test_loss"]
        print(
            f"trained {len(m['seeds'])} seed(s) of a {config.model.kind} model on "
            f"{m['pairs']['train']} pairs ({m['ensemble_mode']})"
        )
        spread = f" ± {bt['std']:.3e}" if len(m["seeds"]) > 1 else ""
        print(f"best test loss: {bt['mean']:.4e}{spread}   (best seed {m['best_member']})")
        print(held_out_text(result.run_dir, config, data))
        print(f"run directory: {result.run_dir}")
    return 0


def _weights_from(run_dir: str, data, train_ids, labels: str) -> list[float]:
    """``--accel-weights-from RUN``: :func:`learn._losses.force_weights` of RUN's best model over
    the training trajectories' samples, with q̈ labels as ``--accel-labels`` takes them."""

    run = load_run(run_dir)
    if run.model_config.kind not in ("lagrangian", "hamiltonian") or (
            run.model_config.n != data.n):
        raise UserError(f"--accel-weights-from {run_dir}: needs a lagrangian or hamiltonian run "
                        f"of the data's n = {data.n} coordinates")
    return list(data_force_weights(run.model, data, train_ids, labels))


def _warn(message: str) -> None:
    """A setting warning of the library, naming the flag instead of the field."""
    from tqdm.auto import tqdm

    field, sep, rest = message.partition(": ")
    if sep and field.isidentifier():
        message = f"--{field.replace('_', '-')}: {rest}"
    message = message.replace("or 'data' to", "or --mass-init data to")
    tqdm.write(f"softpinn: warning: {message}", file=sys.stderr)


#: train flags that are not settings of the run
_RUN_FLAGS = frozenset({"out", "resume", "force", "quiet", "json", "given", "coordinator",
                        "num_processes", "process_id", "cluster", "accel_weights_from"})
_MODEL_FLAGS = frozenset({"model", "width", "depth", "activation", "damping_form", "input_form",
                          "eps", "mass_init", "state", "float32", "known_input", *NETS})


def _resumed_with_flags(args, stored, data):
    """The stored configuration with the settings typed again on the command line (the library
    keeps those that may change on resume and refuses the others, naming them)."""
    import dataclasses


    given = set(args.given) - _RUN_FLAGS
    if args.model == stored.model.kind:  # the run's own kind typed again: no change
        given.discard("model")
    elif "model" in given:
        raise UserError(f"--resume: the run holds a {stored.model.kind} model; --model "
                        f"{args.model} cannot continue it (train a new run into another --out)")
    fields = {f.name for f in dataclasses.fields(stored)}
    changes = {name: getattr(args, name) for name in given & fields}
    if given & {"test_trajectories", "test_count"}:
        changes["test_trajectories"] = (
            args.test_count if args.test_trajectories is None else tuple(args.test_trajectories)
        )
    if given & _MODEL_FLAGS:
        if args.model is None:
            args.model = stored.model.kind

        split = changes.get("test_trajectories", stored.test_trajectories)
        train_ids, _ = split_trajectories(data, test=split, seed=stored.split_seed)
        changes["model"] = _model_config(args, data.n, data.m, data, train_ids)
    return dataclasses.replace(stored, **changes) if changes else stored


def _nulls(obj):
    import math

    if isinstance(obj, dict):
        return {k: _nulls(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nulls(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
