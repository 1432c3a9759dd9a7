"""The matrix-equivalence analysis end to end: evaluate the true model (CasADi, via
``softpinn.symbolic.TrueModel``) and a learned model (JAX, ``model.matrices`` under ``jax.vmap``)
at the same batch of q, run the fits of :mod:`bridge.transforms`, and compare the force terms
along data samples (:mod:`.forces`) and what those show of the inertia (:mod:`.excitation`).

CasADi evaluation stays outside ``jit``: both sides are turned into numpy arrays at the same q
and compared there (STYLE, bridge/4). :mod:`.writer` writes an :class:`AnalysisResult`'s files.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softpinn.bridge.analysis.excitation import sample_share
from softpinn.bridge.analysis.forces import ForceComparison, compare_forces
from softpinn.bridge.analysis.sweeps import Sweeps, compute_sweeps
from softpinn.bridge.analysis.transforms import (
    MATRICES,
    TRANSFORMS,
    MatrixStack,
    TransformResult,
    as_stack,
    check_q,
    fit_transform,
    to_jsonable,
)
from softpinn.errors import UserError
from softpinn.learn.plots import coordinate_unit
from softpinn.progress import Progress, ProgressFn

DEFAULT_TRANSFORMS = ("pointwise", "joint", "alpha", "constant", "smooth")


@dataclass(frozen=True, eq=False)
class AnalysisResult:
    """What :func:`analyze` found: the q, both sides' matrices and one fit per transform."""

    q: np.ndarray
    true: MatrixStack
    learned: MatrixStack
    learned_kind: str | None
    results: Mapping[str, TransformResult]
    meta: Mapping[str, Any] = field(default_factory=dict)
    forces: ForceComparison | None = None
    accelerations: ForceComparison | None = None
    sweeps: Sweeps | None = None
    excitation: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """Every number, JSON-ready (NaN and inf as None)."""
        side = lambda s: {k: getattr(s, k) for k in s.present}
        return to_jsonable(
            {
                "q": self.q,
                "learned_kind": self.learned_kind,
                "meta": dict(self.meta),
                "true": side(self.true),
                "learned": side(self.learned),
                "transforms": {k: r.to_dict() for k, r in self.results.items()},
                "forces": None if self.forces is None else self.forces.to_dict(),
                "accelerations": (
                    None if self.accelerations is None else self.accelerations.to_dict()
                ),
                "sweeps": None if self.sweeps is None else self.sweeps.to_dict(),
                "excitation": self.excitation,
            }
        )


def sample_q(low: Sequence[float], high: Sequence[float], count: int, *, seed: int = 0):
    """``count`` configurations drawn uniformly from the box [low, high] (seeded)."""
    lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    if lo.ndim != 1 or lo.shape != hi.shape:
        raise UserError(
            f"low, high: expected two vectors of one length, got {lo.shape}, {hi.shape}"
        )
    if np.any(hi < lo):
        raise UserError(f"high: expected >= low in every coordinate, got low {lo}, high {hi}")
    if int(count) != count or count < 1:
        raise UserError(f"count: expected an integer >= 1, got {count!r}")
    return np.random.default_rng(seed).uniform(lo, hi, (int(count), lo.size))


def analysis_q(spec: Any, *, count: int = 200, seed: int = 0, paper: bool = True):
    """The q to analyse for a model spec: the paper's table q (``[training] matrix_q`` of the
    presets: Tables I, II, V-IX) followed by ``count`` q drawn uniformly from the box of
    initial configurations the data were generated from (``[data] q0_low``, ``q0_high``).

    Returns ``(q, k)``: q (k + count, n) with the paper's k q first.
    """
    n = int(spec.n)
    training = dict(getattr(spec, "training", {}) or {})
    data = dict(getattr(spec, "data", {}) or {})
    table = np.asarray(training.get("matrix_q", []) if paper else [], dtype=np.float64)
    table = table.reshape(-1, n) if table.size else np.zeros((0, n))
    if count:
        if "q0_low" not in data or "q0_high" not in data:
            raise UserError(
                f"model {getattr(spec, 'name', '?')!r}: no [data] q0_low/q0_high to sample q "
                "from; give the q explicitly"
            )
        sampled = sample_q(data["q0_low"], data["q0_high"], count, seed=seed)
        if sampled.shape[1] != n:
            raise UserError(f"[data] q0_low: expected length n = {n}, got {sampled.shape[1]}")
    else:
        sampled = np.zeros((0, n))
    q = np.concatenate([table, sampled])
    if len(q) == 0:
        raise UserError("analysis_q: no q (no paper table q and count = 0)")
    return q, len(table)


def true_matrices(true_model: Any, q: np.ndarray) -> MatrixStack:
    """M, M^-1, D, G, A of the true model at q (N, n): a ``TrueModel`` (methods batched over
    (N, n)), or matrices already evaluated (a dict or :class:`MatrixStack`)."""
    if isinstance(true_model, MatrixStack | Mapping):
        return as_stack(true_model, "true")
    out = {}
    for key in MATRICES:
        fn = getattr(true_model, key, None)
        if callable(fn):
            out[key] = np.asarray(fn(q), dtype=np.float64)
    if not out:
        raise UserError(
            f"true model: {type(true_model).__name__} has none of the methods {list(MATRICES)}"
        )
    if "G" in out and out["G"].ndim == 1:  # n = 1 batched as (N,)
        out["G"] = out["G"][:, None]
    return MatrixStack.from_mapping(out, name="true")


def learned_matrices(learned_model: Any, q: np.ndarray) -> MatrixStack:
    """The learned model's matrices at q: ``jax.vmap(model.matrices)(q)`` as numpy, or
    matrices already evaluated (a dict or :class:`MatrixStack`)."""
    if isinstance(learned_model, MatrixStack | Mapping):
        return as_stack(learned_model, "learned")
    fn = getattr(learned_model, "matrices", None)
    if not callable(fn):
        raise UserError(
            f"learned model: {type(learned_model).__name__} has no matrices(q) method "
            "(a black-box model has no M, D, G, A to compare)"
        )
    import jax.numpy as jnp

    # one compiled call: eager vmap compiles every primitive on its own (13 s against 2.5 s
    # for a small Hamiltonian net on a busy 2-core machine)
    out = _batched_matrices(learned_model, jnp.asarray(q))
    return MatrixStack.from_mapping(
        {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}, name="learned"
    )


@functools.cache
def _jitted(method: str) -> Callable:
    """``method`` of a model over a batch, compiled once per process: the model is an argument,
    so models of one architecture (a task's variants, an ensemble's members) share the compiled
    program; a lambda jitted at each call compiled it again for every model."""
    import equinox as eqx
    import jax

    return eqx.filter_jit(lambda model, *a: jax.vmap(getattr(model, method))(*a))


def _batched_matrices(model, q):
    return _jitted("matrices")(model, q)


def _batched_qdd(model, q, qd, u):
    return _jitted("qdd")(model, q, qd, u)


def _kind_of(learned_model: Any) -> str | None:
    config = getattr(learned_model, "config", None)
    return getattr(config, "kind", None)


def analyze(
    true_model: Any,
    learned_model: Any,
    q_points: Any,
    *,
    transforms: Sequence[str] = DEFAULT_TRANSFORMS,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    progress: ProgressFn | None = None,
    samples: tuple | None = None,
) -> AnalysisResult:
    """Evaluate both models at ``q_points`` (N, n) and run each transform.

    ``options`` maps a transform name to its keyword options (see :mod:`bridge.transforms`),
    e.g. ``{"smooth": {"degree": 3, "ridge": 1e-8}}``. For a Hamiltonian model (config kind
    ``"hamiltonian"``) the direct comparison (no transform, P = I) is added first.
    ``progress(event)`` is told each stage as it finishes (a :class:`softpinn.progress.Progress`
    of unit "stage", its name as ``label``).

    ``samples``: data samples ``(q, qd, u)`` or ``(q, qd, u, meta)`` (see
    :func:`bridge.forces.data_samples`); both models' force terms G, D q̇, A u and their sum are
    then compared along them (:func:`bridge.forces.compare_forces`; a Lagrangian model's
    divided by the fitted α, and only when ``"alpha"`` is among the transforms), and so are the
    accelerations they give, M⁻¹ times each (``accelerations``; any P(q) leaves them alone, so
    they need no transform).
    """
    transforms = (transforms,) if isinstance(transforms, str) else tuple(transforms)
    for name in transforms:
        if name not in TRANSFORMS:
            raise UserError(f"transform: unknown {name!r}; expected one of {list(TRANSFORMS)}")
    options = dict(options or {})
    for name in options:
        if name not in transforms:
            raise UserError(f"options: {name!r} is not among the transforms {list(transforms)}")
    kind = _kind_of(learned_model)
    if kind == "hamiltonian" and "direct" not in transforms:
        transforms = ("direct",) + transforms
    n = getattr(true_model, "n", None)
    q = np.asarray(q_points, dtype=np.float64)
    if q.ndim == 1:
        q = q[None, :]
    if n is not None:
        q = check_q(q, len(q), int(n))
    elif q.ndim != 2:
        raise UserError(f"q: expected shape (N, n), got {q.shape}")
    total = 2 + len(transforms)
    true = true_matrices(true_model, q)
    if progress:
        progress(Progress(done=1, total=total, unit="stage", label="true model"))
    learned = learned_matrices(learned_model, q)
    if progress:
        progress(Progress(done=2, total=total, unit="stage", label="learned model"))
    check_q(q, true.N, true.n)
    results = {}
    for i, name in enumerate(transforms):
        results[name] = fit_transform(name, true, learned, q, **dict(options.get(name, {})))
        if progress:
            progress(Progress(done=3 + i, total=total, unit="stage", label=name))
    forces = accelerations = excitation = None
    if samples is not None:
        forces, accelerations = _forces(true_model, learned_model, kind, results, samples)
        excitation = sample_share(true_model, samples)
    spec = getattr(true_model, "spec", None)
    names = getattr(spec, "coordinate_names", None)
    units = None
    if names is not None:

        units = [coordinate_unit(c, spec.kind) for c in names]
    sweeps = None
    if not isinstance(true_model, MatrixStack | Mapping) and not isinstance(
            learned_model, MatrixStack | Mapping):  # models, not matrices already evaluated
        sweeps = compute_sweeps(lambda x: true_matrices(true_model, x),
                                lambda x: learned_matrices(learned_model, x), q, kind, results,
                                names=names, units=units)
    meta = {
        "N": true.N,
        "n": true.n,
        "m": true.m,
        "true_model": getattr(spec, "name", type(true_model).__name__),
        "learned_kind": kind,
        "transforms": list(transforms),
        "options": options,
        "coordinates": None if names is None else list(names),
        "model_kind": getattr(spec, "kind", None),
    }
    return AnalysisResult(q, true, learned, kind, results, meta, forces, accelerations, sweeps,
                          excitation)


def _forces(true_model, learned_model, kind, results, samples):
    """The force comparison (None for a Lagrangian model without the alpha transform) and the
    acceleration comparison along the samples."""
    if not isinstance(samples, tuple | list) or len(samples) not in (3, 4):
        raise UserError("samples: expected (q, qd, u) or (q, qd, u, meta)")
    qs, qd, u = samples[:3]
    meta = dict(samples[3]) if len(samples) == 4 else {}
    qs = np.asarray(qs, dtype=np.float64)
    if qs.ndim != 2 or len(qs) == 0:
        raise UserError(f"samples: q expected shape (N, n) with N > 0, got {qs.shape}")
    scale = None
    if kind == "hamiltonian":
        scale = 1.0
    elif "alpha" in results and np.isfinite(results["alpha"].alpha):
        scale = 1.0 / results["alpha"].alpha
    n = getattr(true_model, "n", None)
    if n is not None:
        check_q(qs, len(qs), int(n))
    true = true_matrices(true_model, qs)
    check_q(qs, true.N, true.n)
    learned = learned_matrices(learned_model, qs)
    if u is None:  # no inputs given: zero inputs
        u = np.zeros((len(qs), true.m or 0))
    forces = None
    if scale is not None:
        fmeta = dict(meta, scale_from="alpha") if kind != "hamiltonian" else meta
        forces = compare_forces(true, learned, qd, u, scale=scale, meta=fmeta)
    accelerations = compare_forces(true, learned, qd, u, frame="acceleration", meta=meta,
                                   qdd=_qdd_pair(true_model, learned_model, qs, qd, u))
    return forces, accelerations


def _qdd_pair(true_model, learned_model, q, qd, u):
    """The true and the learned q̈ at the samples, or None when either model cannot give it
    (matrices given as arrays, stand-ins without ``qdd``)."""
    if isinstance(learned_model, MatrixStack | Mapping) or not hasattr(learned_model, "qdd"):
        return None
    if not callable(getattr(true_model, "qdd", None)):
        return None
    import jax.numpy as jnp

    qd, u = np.asarray(qd, dtype=np.float64), np.asarray(u, dtype=np.float64)
    true = np.asarray(true_model.qdd(q, qd, u if u.shape[1] else None), dtype=np.float64)
    learned = _batched_qdd(learned_model, jnp.asarray(q), jnp.asarray(qd), jnp.asarray(u))
    return true.reshape(q.shape), np.asarray(learned, dtype=np.float64)
