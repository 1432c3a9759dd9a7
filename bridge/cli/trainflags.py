"""The training flags ``softpinn train`` and ``softpinn sweep`` share: one flag per setting of
:class:`softpinn.learn.TrainConfig` and of the network (:class:`softpinn.learn.ModelConfig`),
with the configs' defaults, help and choices (the defaults live in the configs alone), and the
network's configuration built from them (:func:`model_config`). Imported when a parser of
those commands is filled in (it imports :mod:`softpinn.learn`)."""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing

from softpinn.errors import UserError
from softpinn.learn import GROUPS, RESUMABLE, ModelConfig, TrainConfig, mass_scale

__all__ = ["CUSTOM", "LINEAR", "LINEAR_FLAGS", "MODEL_KINDS", "NETS", "RESUMABLE", "SWEEP_OWN",
           "add_network_flags", "add_setting_flags", "check_linear_flags", "model_config",
           "track_given"]

MODEL_KINDS = ("lagrangian", "hamiltonian", "blackbox", "lagrangian-hessian")
NETS = ("mass", "potential", "damping", "input", "hidden")
#: ``train --model linear``: the least-squares baselines (issue 43), fitted in closed form
LINEAR = "linear"
#: the flags ``--model linear`` takes (their destinations); every other one is a network's
LINEAR_FLAGS = frozenset({"model", "out", "force", "quiet", "json", "test_trajectories",
                          "test_count", "split_seed", "actuator"})
#: Train settings whose flags are not generated one to one from their field.
CUSTOM = ("test_trajectories",)
#: train flags the sweep spells otherwise or leaves out: its --seeds and --samples are its own,
#: and a trial trains one seed, so the ensemble mode does not apply
SWEEP_OWN = ("seeds", "samples", "test_trajectories", "ensemble")


def _model_defaults() -> dict:
    return {f.name: f.default for f in dataclasses.fields(ModelConfig)}


def _devices(text: str) -> int:
    """--devices N, or all (0, as the setting's help says)."""
    if text == "all":
        return 0
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a count or 'all', got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a count >= 1, or 'all' (or 0), got {value}")
    return value


def _validation(text: str):
    """--validation auto | K (a count; 0: none) | X (a fraction in (0, 1)) | ID,ID,... (ids)."""
    text = text.strip()
    try:
        if text == "auto":
            return text
        if "," in text:
            return tuple(int(i) for i in text.split(",") if i.strip())
        if any(c in text for c in ".eE"):
            value = float(text)
            if not 0.0 < value < 1.0:
                raise argparse.ArgumentTypeError(f"a fraction must be in (0, 1), got {text!r}")
            return value
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected auto, a count, a fraction in (0, 1) or ids ID,ID,..., got {text!r}"
        ) from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a count >= 0, got {value}")
    return value


def _horizons(text: str) -> tuple[int, ...]:
    """--rollout-schedule 1,4,16,64: horizons in steps (checked further by TrainConfig)."""
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected horizons in steps separated by commas, "
                                         f"such as 1,4,16,64, got {text!r}") from None


def _split_flags(group) -> None:
    group.add_argument("--test-trajectories", type=int, nargs="+", default=None, metavar="ID",
                       help="trajectory ids held out for testing (default: the test split the data "
                       "file records, from simulate's spec or import --test-trajectories; "
                       "else 20%% drawn at random)")
    group.add_argument("--test-count", type=int, default=None, metavar="K",
                       help="hold out K trajectories drawn at random")


def add_setting_flags(parser, *, skip=CUSTOM, title=str, split_flags=_split_flags) -> None:
    """One flag per :class:`softpinn.learn.TrainConfig` setting, in argument groups (budget,
    optimizer, loss, split, ensemble, devices), with the field's default, help and choices: the
    defaults live in the config alone. ``skip``: settings whose flags the caller spells itself;
    ``title(group)``: the groups' titles; ``split_flags(group)`` adds the flags of the split
    group that are not one field each (``softpinn sweep`` uses all three)."""
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
            elif f.name == "rollout_schedule":
                kw.update(type=_horizons, metavar="H,H,...")
            elif f.name == "validation":  # softpinn train applies auto where it is not given
                kw.update(type=_validation, metavar="auto|K|X|ID,ID")
            elif typing.get_origin(hint) is tuple:  # accel_weights: n numbers
                kw.update(type=float, nargs="+", metavar="W")
            elif f.metadata.get("choices"):
                kw["choices"] = f.metadata["choices"]
            else:
                kw["type"] = hint
                named = {"init": "RUN", "actuator": "TAU:DELAY|..."}
                kw["metavar"] = "N" if hint is int else named.get(f.name, "X")
            g.add_argument(f"--{f.name.replace('_', '-')}", **kw)
        if group == "split":
            split_flags(g)


def add_network_flags(parser, title: str = "network") -> None:
    """The flags of the network (:class:`softpinn.learn.ModelConfig`), defaults from its
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


def check_linear_flags(args) -> None:
    """Refuse, in one line naming the flag, a network's flag given with ``--model linear``
    (its models are fitted in closed form: no epochs, optimizer, network or devices)."""
    extra = sorted(set(getattr(args, "given", ())) - LINEAR_FLAGS)
    if extra:
        flag = f"--{extra[0].replace('_', '-')}"
        raise UserError(f"{flag} applies to network models, not --model linear (its ARX and "
                        "linear second-order models are fitted in closed form)")


def model_config(args, n: int, m: int, data=None, train_ids=None):
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
        # deferred: casadi, for --known-input MODEL alone (train needs no casadi otherwise)
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

